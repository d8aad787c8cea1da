"""The plant: the robot's true dynamics (eq. (1)) advanced one control period at a time.

:class:`PlantSimulator` owns the true state ``(X, Z)``, the Hertz contact
state and the tick counter.  ``output()`` gives the ground truth at ``t_k``;
``step(G)`` integrates ``[t_k, t_{k+1}]`` under the gradient ``G`` applied by
the coil (held over the period, zero-order hold), with the compiled adaptive
integrator of :mod:`vesselbot_ros.physics.integrator` (sub-steps inside the
period).  Tick times are ``t_k = t0 + k / rate`` (no accumulated drift).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import (
    OK,
    IntegratorHolder,
    IntegratorParams,
    failure_message,
    integrate,
    integrator_vector,
    new_workspace,
    plant_output,
)
from vesselbot_ros.physics.kernel import TERM_NAMES
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.vessels.tree_field import packed_vessel, vessel_geom

__all__ = ["PlantOutput", "PlantSimulator", "CompiledPlant", "TERM_NAMES"]


@dataclasses.dataclass(frozen=True)
class CompiledPlant:
    """The plant in the compiled loop's form: what its step (``physics.integrator.integrate``) and its output
    (``wall_and_forces``) read.

    Attributes:
        geom: The vessel (the integrator's geometry edge: packed parameters, or a tree's ``(p, W, F, fh)``).
        ig: The integrator's settings, packed (:func:`~vesselbot_ros.physics.integrator.integrator_vector`).
        state0: ``(X, Z)`` at tick 0 (2 d,); each run gets a copy.
    """

    geom: Any
    ig: npt.NDArray[np.float64]
    state0: npt.NDArray[np.float64]


class PlantOutput(NamedTuple):
    """Ground truth at one tick.

    Attributes:
        t_s: Tick time (s).
        p: (d,) true position, m, frame W.
        v: (d,) true velocity, m/s.
        delta_m: Signed distance to the nearest wall (m), > 0 = penetration.
        wall: +1 upper wall, -1 lower wall (the nearest one).
        in_contact: ``delta_m > 0``.
        contact_phase: 0 free, 1 loading (15), 2 unloading (16).
        forces: (8, d) force terms (N) in ``TERM_NAMES`` order under the
            gradient currently applied, or None if not asked for.
    """

    t_s: float
    p: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]
    delta_m: float
    wall: float
    in_contact: bool
    contact_phase: int
    forces: npt.NDArray[np.float64] | None


class PlantSimulator(IntegratorHolder):
    """True robot dynamics, advanced one control period per :meth:`step`, on the vessel's axes.

    In the plane (a straight vessel or a planar network) the state is ``(x, z, vx, vz)``; in a 3-D tree
    (``physics.vessel.network`` a tree in space, ``p0_m`` of three values) ``(x, y, z, vx, vy, vz)``, the kernel
    :mod:`vesselbot_ros.physics.tree_vessel`.  The ports are the same on (d,) vectors (:class:`PlantOutput`: (d,) ``p``,
    ``v``, (8, d) forces).

    Args:
        physics: True physics parameters.
        integrator: Integrator settings.
        dt_control_s: Control period (s).
        p0_m: (d,) initial position (m): its length is the axis count.
        v0_m_per_s: (d,) initial velocity (m/s); zero if None.
        t0_s: Initial time (s).
    """

    def __init__(
        self,
        physics: PhysicsParams,
        integrator: IntegratorParams,
        dt_control_s: float,
        p0_m: npt.ArrayLike,
        v0_m_per_s: npt.ArrayLike | None = None,
        t0_s: float = 0.0,
    ) -> None:
        if not (math.isfinite(dt_control_s) and dt_control_s > 0.0):
            raise ModelInputError(f"dt_control_s must be finite and > 0, got {dt_control_s!r}")
        p0 = np.asarray(p0_m, dtype=np.float64).ravel()
        d = p0.shape[0]
        v0 = np.zeros(d) if v0_m_per_s is None else np.asarray(v0_m_per_s, dtype=np.float64).ravel()
        y = np.concatenate([p0, v0])
        if d not in (2, 3) or y.shape != (2 * d,) or not np.all(np.isfinite(y)):
            raise ModelInputError(f"initial state must be finite (d,) + (d,), d = 2 or 3, got {p0_m!r}, {v0_m_per_s!r}")
        self.dims = d
        self.physics = physics
        self.integrator = integrator  # and its packed vector (the setter)
        self.p, self.packed = packed_vessel(physics, d)  # a tree in space: the 3-D kernel's packed tree
        self._dt = float(dt_control_s)
        self._t0 = float(t0_s)
        self._k = 0
        self._y = y
        self._contact = np.zeros(4)
        self._g = np.zeros(d)
        self._zero = np.zeros(d)
        self._h = integrator.max_step_s
        self._forces = np.empty((8, d))
        self._work, self._fbuf, self._sc = new_workspace(d)  # integrator scratch, allocated once
        self.stats = np.zeros(4, dtype=np.int64)  # accepted, rejected, rhs evaluations, forced steps

    @property
    def geom(self) -> Any:
        """The vessel the integrator flies the bead in (:mod:`vesselbot_ros.physics.integrator`'s geometry edge):
        the packed parameters ``p`` of a straight vessel or a planar network, a tree's ``(p, W, F, fh)``."""
        return vessel_geom(self.p, self.packed)

    def compiled(self) -> CompiledPlant:
        """This plant in the compiled loop's form (its vessel, integrator settings and current state)."""
        return CompiledPlant(self.geom, integrator_vector(self.integrator), self.state)

    @property
    def t_s(self) -> float:
        """Current tick time (s)."""
        return self._t0 + self._k * self._dt

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(2 d,) copy of ``(X, Z)`` (m, m/s)."""
        return self._y.copy()

    @property
    def contact_state(self) -> npt.NDArray[np.float64]:
        """(4,) copy of the contact state [phase, delta_max, F_max, delta_0]."""
        return self._contact.copy()

    def output(self, with_forces: bool = False) -> PlantOutput:
        """Ground truth at the current tick (see :class:`PlantOutput`)."""
        t = self.t_s
        y = self._y
        d = self.dims
        delta, wall = plant_output(t, y, self._g, self._contact, self.geom, self._forces, self._sc, with_forces)
        return PlantOutput(t, y[:d].copy(), y[d:].copy(), float(delta), float(wall), bool(delta > 0.0),
                           int(self._contact[0]), self._forces.copy() if with_forces else None)

    def step(self, applied_gradient_T_per_m: npt.ArrayLike) -> None:
        """Integrate ``[t_k, t_{k+1}]`` under the applied gradient (T/m, (d,)).

        Raises:
            ModelInputError: on a non-finite or wrongly shaped gradient, or if
                the integration fails (step too small, non-finite state).
        """
        d = self.dims
        g = np.array(applied_gradient_T_per_m, dtype=np.float64)
        if g.shape != (d,) or not bool(np.isfinite(g).all()):
            raise ModelInputError(f"plant: applied gradient must be a finite ({d},) array, got {applied_gradient_T_per_m!r}")
        self._g = g
        t0 = self.t_s
        t1 = self._t0 + (self._k + 1) * self._dt
        code, self._h = integrate(t0, t1, self._y, g, self._zero, self._contact, self.geom, self._h, self._ig, self.stats,
                                  self._work, self._fbuf, self._sc)
        if code != OK:
            raise ModelInputError(failure_message(f"tick {self._k}: plant", t0, t1, code, self._y.tolist()))
        self._k += 1
