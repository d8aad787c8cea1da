"""The compiled controller's calling convention: one numba signature that every compiled controller kind implements.

The compiled closed loop (:mod:`vesselbot_ros.sim.compiled_loop`) calls the
controller through a function pointer of type :data:`CONTROLLER_STEP` (a numba
``cfunc``), whatever its kind: a new compiled controller is its own module and
one registration (:mod:`vesselbot_ros.sim.kinds`), not a branch in the loop.
numba compiles the loop once for this type and caches it; any controller of
the signature runs in it.

The step, once per control tick::

    status = step(prm, state, model_p, work, fbuf, t, x0, x1, z0, z1, age, flow_scale,
                  pr0, pr1, vr0, vr1, ar0, ar1, out)

* ``prm``: the kind's parameters (read-only); ``state``: its state, updated
  in place (a fresh copy of :attr:`CompiledController.state0` per run);
  ``work`` (:attr:`CompiledController.work_size`) and ``fbuf`` (8, 2): scratch;
* ``model_p``: the controller's model of the plant, packed
  (:func:`vesselbot_ros.vessels.cfd.packed_params` of the model physics);
* the estimate ``x`` (m), ``z`` (m/s), the age of its last measurement
  ``age`` (s) and the observer's blood-velocity scale ``flow_scale``; the
  reference sample ``p``, ``v``, ``a``;
* writes ``out`` (:data:`CONTROLLER_OUT_SIZE`): the gradient (T/m, 2), the
  acceleration asked for (m/s^2, 2), the flow scale and the magnetisation
  scale the controller worked with;
* returns a status: 0 ok, 1 stale, 2 non-finite (a safe action was taken),
  or :data:`STEP_FLOW_SCALE_INVALID`: an error (``out[4]`` holds the flow
  scale it refused); the loop stops there.

The Python stage of the kind must give the same doubles (the per-tick loop and
the nodes call it): the built-in law calls the very same compiled functions.
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

__all__ = ["CONTROLLER_STEP", "CONTROLLER_OUT_SIZE", "STEP_FLOW_SCALE_INVALID", "CompiledController", "lazy_step"]

_F = types.float64
_V = types.float64[::1]
_RO = types.Array(types.float64, 1, "C", readonly=True)  # the packed model: shared by every run, never written
#: The numba signature of a compiled controller step (module docstring).
CONTROLLER_STEP = types.int64(_V, _V, _RO, _V, types.float64[:, ::1], _F, _F, _F, _F, _F, _F, _F,
                              _F, _F, _F, _F, _F, _F, _V)
#: Length of a step's ``out``: [g x, g z, U x, U z, flow scale, magnetisation scale].
CONTROLLER_OUT_SIZE = 6
#: A step's status for a flow scale it cannot use: the loop stops with the per-tick loop's error.
STEP_FLOW_SCALE_INVALID = 3


@dataclasses.dataclass(frozen=True)
class CompiledController:
    """A controller stage in the compiled loop's form.

    Attributes:
        step: A numba ``cfunc`` of :data:`CONTROLLER_STEP`.
        prm: Its parameters (float64, contiguous).
        state0: Its state at tick 0 (float64, contiguous; each run gets a copy).
        work_size: Length of its ``work`` scratch.
    """

    step: Any
    prm: npt.NDArray[np.float64]
    state0: npt.NDArray[np.float64]
    work_size: int

    def __post_init__(self) -> None:  # own writable copies, in the layout the signature names
        object.__setattr__(self, "prm", np.array(self.prm, dtype=np.float64, order="C"))
        object.__setattr__(self, "state0", np.array(self.state0, dtype=np.float64, order="C"))


def lazy_step(py_func: Callable[..., int]) -> Callable[[], Any]:
    """``py_func`` (a module-level function of the step's arguments) as a :data:`CONTROLLER_STEP` ``cfunc``, made
    on the first call of the returned function and kept.

    Making a ``cfunc`` loads it from numba's cache (or compiles it): about 0.1 s that a process which never
    runs the compiled loop (a node, a ``--help``) should not pay at import.
    """

    @functools.cache
    def step() -> Any:
        return numba.cfunc(CONTROLLER_STEP, cache=True)(py_func)

    step.__doc__ = f"The compiled step of ``{py_func.__name__}`` (made on first use)."
    return step
