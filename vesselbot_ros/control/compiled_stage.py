"""The compiled controller's calling convention: one numba signature per vessel geometry, which every compiled
controller kind implements once, on any number of axes.

The compiled closed loop (:mod:`vesselbot_ros.sim.compiled_loop`) calls the controller through a function pointer
(a numba ``cfunc``) whatever its kind: a new compiled controller is its own module and one registration
(:mod:`vesselbot_ros.sim.kinds`), not a branch in the loop.  The step, once per control tick::

    status = step(prm, state, geom, work, fbuf, sc, t, est, p_ref, v_ref, a_ref, out)

* ``prm``: the kind's parameters (read-only); ``state``: its state, updated in place (a fresh copy of
  :attr:`CompiledController.state0` per run); ``work`` (:attr:`CompiledController.work_size`), ``fbuf`` (8, d)
  and ``sc`` (4, d): scratch;
* ``geom``: the controller's model of the vessel (:attr:`vesselbot_ros.control.model.DynamicsModel.geom`: the
  packed model physics of a straight vessel or planar network, or a 3-D tree's ``(p, W, F, fh)``); its forces
  come from :func:`model_f_into` (``physics.integrator``'s geometry edge);
* ``est`` (2 d + 2,): the estimate ``[X (d), Z (d), age of its last measurement (s), the observer's
  blood-velocity scale]``; ``p_ref``, ``v_ref``, ``a_ref`` (d,): the reference sample;
* writes ``out`` (:func:`controller_out_size`, 2 d + 2): the gradient (T/m, d), the acceleration asked for
  (m/s^2, d), the flow scale and the magnetisation scale the controller worked with;
* returns a status: 0 ok, 1 stale, 2 non-finite (a safe action was taken), or :data:`STEP_FLOW_SCALE_INVALID`:
  an error (``out[2 d]`` holds the flow scale it refused); the loop stops there.

The axis count d is the length of ``p_ref``.  numba makes the ``cfunc`` of a kind once per geometry type
(:func:`lazy_step`), so the loop is compiled once per geometry, and any controller of the signature runs in it.
The Python stage of the kind must give the same doubles (the per-tick loop and the nodes call it): the built-in
laws call the very same compiled functions.
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

from vesselbot_ros.physics.integrator import forces_at, mass_of

__all__ = ["controller_step_type", "controller_out_size", "STEP_FLOW_SCALE_INVALID", "CompiledController",
           "lazy_step", "model_f_into", "geom_type"]

_F = types.float64
_V = types.float64[::1]
_M = types.float64[:, ::1]
_RO = types.Array(types.float64, 1, "C", readonly=True)  # the packed model: shared by every run, never written
#: A step's status for a flow scale it cannot use: the loop stops with the per-tick loop's error.
STEP_FLOW_SCALE_INVALID = 3


def controller_out_size(dims: int) -> int:
    """Length of a step's ``out`` on ``dims`` axes: [g (d), U (d), flow scale, magnetisation scale]."""
    return 2 * int(dims) + 2


def geom_type(geom: Any) -> Any:
    """The numba type of a model geometry as the steps take it: its packed parameters read-only."""
    if isinstance(geom, np.ndarray):
        return _RO
    _p, *rest = geom
    return types.Tuple((_RO, *(numba.typeof(r) for r in rest)))


def controller_step_type(gtype: Any) -> Any:
    """The numba signature of a compiled controller step over a model geometry of type ``gtype`` (module docstring)."""
    return types.int64(_V, _V, gtype, _V, _M, _M, _F, _V, _V, _V, _V, _V)


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


def lazy_step(py_func: Callable[..., int]) -> Callable[[Any], Any]:
    """``py_func`` (a module-level function of the step's arguments) as a ``cfunc`` of
    :func:`controller_step_type`, made on the first call for a geometry type and kept.

    Making a ``cfunc`` loads it from numba's cache (or compiles it): about 0.1 s that a process which never
    runs the compiled loop (a node, a ``--help``) should not pay at import.
    """

    @functools.cache
    def step(gtype: Any) -> Any:
        return numba.cfunc(controller_step_type(gtype), cache=True)(py_func)

    step.__doc__ = f"The compiled step of ``{py_func.__name__}`` for a geometry type (made on first use)."
    return step


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # _nrt: an option numba's stubs omit
def model_f_into(t, x, z, geom, free, fbuf, sc, y, g0, f):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The model's ``F(X, Z)`` (m/s^2, (d,)) at ``t`` into ``f``: every force but the motive one over the mass, at the
    contact state ``free`` (zeros: memoryless).  ``y`` (2 d,) scratch, ``g0`` (d,) zeros."""
    d = x.shape[0]
    for c in range(d):
        y[c] = x[c]
        y[d + c] = z[c]
    forces_at(t, y, g0, free, geom, fbuf, sc)
    m = mass_of(geom)
    for c in range(d):
        f[c] = fbuf[7, c] / m
