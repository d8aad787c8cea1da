"""The compiled stages' calling conventions: one numba signature per role and vessel geometry, which every compiled
kind of the role implements once, on any number of axes.

The compiled closed loop (:mod:`vesselbot_ros.sim.compiled_loop`) calls the observer and the controller through
function pointers (numba ``cfunc`` objects) whatever their kinds: a new compiled kind is its own module and one
registration (:mod:`vesselbot_ros.sim.kinds`: its ``compile`` gives a :class:`CompiledObserver` or a
:class:`CompiledController`), not a branch in the loop.  numba makes the ``cfunc`` of a kind once per geometry type
(:func:`lazy_step`), so the loop is compiled once per geometry, and any kind of the signature runs in it.  The
Python stage of the kind must give the same doubles (the per-tick loop and the nodes call it): the built-in kinds
call the very same compiled functions.

The controller's step, once per control tick::

    status = step(prm, state, geom, work, fbuf, sc, t, est, p_ref, v_ref, a_ref, out)

* ``prm``: the kind's parameters (read-only); ``state``: its state, updated in place (a fresh copy of
  :attr:`CompiledController.state0` per run); ``work`` (:attr:`CompiledController.work_size`), ``fbuf`` (8, d)
  and ``sc`` (4, d): scratch;
* ``geom``: the controller's model of the vessel (:attr:`vesselbot_ros.control.model.DynamicsModel.geom`: the
  packed model physics of a straight vessel or planar network, or a 3-D tree's ``(p, W, F, fh)``), its packed
  parameters read-only; its forces come from :func:`model_f_into` (``physics.integrator``'s geometry edge);
* ``est`` (2 d + 2,): the estimate ``[X (d), Z (d), age of its last measurement (s), the observer's
  blood-velocity scale]``; ``p_ref``, ``v_ref``, ``a_ref`` (d,): the reference sample;
* writes ``out`` (:func:`controller_out_size`, 2 d + 2): the gradient (T/m, d), the acceleration asked for
  (m/s^2, d), the flow scale and the magnetisation scale the controller worked with;
* returns a status: 0 ok, 1 stale, 2 non-finite (a safe action was taken), or :data:`STEP_FLOW_SCALE_INVALID`:
  an error (``out[2 d]`` holds the flow scale it refused); the loop stops there.

The observer's step, once per tick::

    code = step(prm, state, istate, geom, work, stats, t, g, has_meas, t_acq, m, out, err)

* ``prm``, ``state`` (float64), ``istate`` (int64), ``work``: the kind's parameters, state (fresh copies of
  :attr:`CompiledObserver.state0` and ``istate0`` per run) and scratch, flat (the step views them in its layout);
* ``geom``: the observer's model of the vessel (as the controller's, its packed parameters writable);
  ``stats`` (4,) int64: the model integrator's counters;
* ``t`` (s), ``g`` (d,): the gradient the coil applied since the last tick (T/m); a frame ``m`` (d,) acquired at
  ``t_acq`` if ``has_meas``;
* writes ``out`` (:func:`observer_step_out_size`, 3 d + 4): ``[X (d), Z (d), age (s), innovation X_hat - Y (d),
  used, rejected, blood-velocity scale]``;
* returns 0, or a failure code with ``err`` (3 + 2 d + 1,) holding its details, which
  :attr:`CompiledObserver.message` words as the per-tick loop's error; the loop stops there.

The axis count d is the length of ``p_ref`` or ``g``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import numba
import numpy as np
import numpy.typing as npt
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from vesselbot_ros.physics.integrator import axes_of, forces_at, mass_of

__all__ = ["controller_step_type", "controller_out_size", "STEP_FLOW_SCALE_INVALID", "CompiledController",
           "observer_step_type", "observer_step_out_size", "CompiledObserver", "lazy_step", "model_f_into",
           "flat_view", "observer_step_at"]

_F = types.float64
_V = types.float64[::1]
_M = types.float64[:, ::1]
#: A step's status for a flow scale it cannot use: the loop stops with the per-tick loop's error.
STEP_FLOW_SCALE_INVALID = 3


def controller_out_size(dims: int) -> int:
    """Length of a step's ``out`` on ``dims`` axes: [g (d), U (d), flow scale, magnetisation scale]."""
    return 2 * int(dims) + 2


def controller_step_type(gtype: Any) -> Any:
    """The numba signature of a compiled controller step over a model geometry of type ``gtype`` (module docstring)."""
    return types.int64(_V, _V, gtype, _V, _M, _M, _F, _V, _V, _V, _V, _V)


def observer_step_out_size(dims: int) -> int:
    """Length of an observer step's ``out`` on ``dims`` axes."""
    return 3 * int(dims) + 4


def observer_step_type(gtype: Any) -> Any:
    """The numba signature of a compiled observer step over a model geometry of type ``gtype`` (module docstring)."""
    return types.int64(_V, _V, types.int64[::1], gtype, _V, types.int64[::1], _F, _V, types.boolean, _F, _V, _V, _V)


@dataclasses.dataclass(frozen=True)
class CompiledObserver:
    """An observer stage in the compiled loop's form.

    Attributes:
        step: ``step(gtype)``: the kind's ``cfunc`` for a model geometry of numba type ``gtype`` (:func:`lazy_step`
            with :func:`observer_step_type`).
        prm: Its parameters (float64, contiguous).
        state0: Its float state at tick 0 (each run gets a copy).
        istate0: Its integer state at tick 0 (int64; each run gets a copy).
        work0: Its scratch at tick 0 (float64; each run gets a copy: a memo in it starts invalid).
        geom: The model geometry it runs on (its Python stage's).
        message: ``message(err)``: the per-tick loop's error for a failure the step reported in ``err``.
    """

    step: Callable[[Any], Any]
    prm: npt.NDArray[np.float64]
    state0: npt.NDArray[np.float64]
    istate0: npt.NDArray[np.int64]
    work0: npt.NDArray[np.float64]
    geom: Any
    message: Callable[[npt.NDArray[np.float64]], str]

    def __post_init__(self) -> None:  # own writable copies, in the layout the signature names
        object.__setattr__(self, "prm", np.array(self.prm, dtype=np.float64, order="C"))
        object.__setattr__(self, "state0", np.array(self.state0, dtype=np.float64, order="C"))
        object.__setattr__(self, "istate0", np.array(self.istate0, dtype=np.int64, order="C"))
        object.__setattr__(self, "work0", np.array(self.work0, dtype=np.float64, order="C"))


@dataclasses.dataclass(frozen=True)
class CompiledController:
    """A controller stage in the compiled loop's form.

    Attributes:
        step: ``step(gtype)``: the kind's ``cfunc`` for a model geometry of numba type ``gtype``
            (:func:`lazy_step` makes it).
        prm: Its parameters (float64, contiguous).
        state0: Its state at tick 0 (float64, contiguous; each run gets a copy).
        work_size: Length of its ``work`` scratch.
    """

    step: Callable[[Any], Any]
    prm: npt.NDArray[np.float64]
    state0: npt.NDArray[np.float64]
    work_size: int

    def __post_init__(self) -> None:  # own writable copies, in the layout the signature names
        object.__setattr__(self, "prm", np.array(self.prm, dtype=np.float64, order="C"))
        object.__setattr__(self, "state0", np.array(self.state0, dtype=np.float64, order="C"))


def lazy_step(py_func: Callable[..., int], signature: Callable[[Any], Any] = controller_step_type,
              nrt: bool = True) -> Callable[[Any], Any]:
    """``py_func`` (a module-level function of the step's arguments) as a ``cfunc`` of ``signature`` (the
    controller's, or :func:`observer_step_type`), made on the first call for a geometry type and kept.

    Making a ``cfunc`` loads it from numba's cache (or compiles it): about 0.1 s that a process which never
    runs the compiled loop (a node, a ``--help``) should not pay at import.  ``nrt=False`` compiles it without
    numba's runtime (a step that allocates nothing and returns no array: no reference counts on its arguments).
    """

    @functools.cache
    def step(gtype: Any) -> Any:
        return numba.cfunc(signature(gtype), cache=True, _nrt=nrt)(py_func)  # type: ignore[call-arg]  # _nrt: an option numba's stubs omit

    step.__doc__ = f"The compiled step of ``{py_func.__name__}`` for a geometry type (made on first use)."
    return step


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # _nrt: an option numba's stubs omit
def model_f_into(t, x, z, geom, free, fbuf, sc, y, g0, f):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The model's ``F(X, Z)`` (m/s^2, (d,)) at ``t`` into ``f``: every force but the motive one over the mass, at the
    contact state ``free`` (zeros: memoryless).  ``y`` (2 d,) scratch, ``g0`` (d,) zeros."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    for c in range(d):
        y[c] = x[c]
        y[d + c] = z[c]
    forces_at(t, y, g0, free, geom, fbuf, sc)
    m = mass_of(geom)
    for c in range(d):
        f[c] = fbuf[7, c] / m


@intrinsic
def _float_ptr(typingctx, address):  # type: ignore[no-untyped-def]  # numba intrinsic: typed at compile time
    """An address (intp) as a ``float64*`` (for :func:`flat_view`)."""
    sig = types.CPointer(types.float64)(types.intp)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]  # llvmlite builder
        return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.float64)))

    return sig, codegen


@numba.njit(cache=True, nogil=True, inline="always")
def flat_view(a, offset, shape):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """A C-contiguous view of ``shape`` on the float64 array ``a`` from ``offset`` (a step's layout over its flat
    state or scratch).  Without a reshape's checks and reference count (about 15 ns each, a dozen per tick for the
    filter): the view lives only while the step runs, and ``a`` outlives it.  The caller keeps it in bounds."""
    return numba.carray(_float_ptr(a.ctypes.data + 8 * offset), shape)  # type: ignore[call-arg]  # the intrinsic takes the typing context itself


@intrinsic
def observer_step_at(typingctx, address, geom):  # type: ignore[no-untyped-def]  # numba intrinsic: typed at compile time
    """The observer step whose ``cfunc`` is at ``address`` (its ``.address``, an int), as the first-class function a
    ``CFunc`` argument unboxes to, for a model geometry of ``geom``'s type.

    A ``cfunc`` passed as an argument costs a compiled function about 20 us per call to type and unbox (numba types
    it in Python and unpickles its signature); an address is an integer.  The caller keeps the ``cfunc`` alive.
    """
    fnty = types.FunctionType(observer_step_type(geom))

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]  # llvmlite builder
        step = cgutils.create_struct_proxy(fnty)(context, builder)  # zero-filled: no Python object, no jit address
        step.c_addr = builder.inttoptr(args[0], context.get_value_type(types.voidptr))
        return step._getvalue()

    return fnty(types.intp, geom), codegen
