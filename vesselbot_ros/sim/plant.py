"""The plant: the robot's true dynamics (eq. (1)) advanced one control period at a time.

:class:`PlantSimulator` owns the true state ``(X, Z)``, the Hertz contact
state and the tick counter.  ``output()`` gives the ground truth at ``t_k``;
``step(G)`` integrates ``[t_k, t_{k+1}]`` under the gradient ``G`` applied by
the coil (held over the period, zero-order hold), with the compiled adaptive
integrator of :mod:`vesselbot_ros.physics.integrator` (sub-steps inside the
period).  Tick times are ``t_k = t0 + k / rate`` (no accumulated drift).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import OK, IntegratorParams, failure_message, integrate, integrator_vector, new_workspace
from vesselbot_ros.physics.kernel import I_R, TERM_NAMES, forces_into, wall_delta_xz
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.physics.plant3d import forces3d_at
from vesselbot_ros.vessels.cfd import packed_params
from vesselbot_ros.vessels.plant_field3d import packed3d

__all__ = ["PlantOutput", "PlantSimulator", "PlantSimulator3D", "TERM_NAMES"]


class PlantOutput(NamedTuple):
    """Ground truth at one tick.

    Attributes:
        t_s: Tick time (s).
        p: (2,) true position, m, frame W.
        v: (2,) true velocity, m/s.
        delta_m: Signed distance to the nearest wall (m), > 0 = penetration.
        wall: +1 upper wall, -1 lower wall (the nearest one).
        in_contact: ``delta_m > 0``.
        contact_phase: 0 free, 1 loading (15), 2 unloading (16).
        forces: (8, 2) force terms (N) in ``TERM_NAMES`` order under the
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


class PlantSimulator:
    """True robot dynamics, advanced one control period per :meth:`step`.

    Args:
        physics: True physics parameters.
        integrator: Integrator settings.
        dt_control_s: Control period (s).
        p0_m: (2,) initial position (m).
        v0_m_per_s: (2,) initial velocity (m/s).
        t0_s: Initial time (s).
    """

    def __init__(
        self,
        physics: PhysicsParams,
        integrator: IntegratorParams,
        dt_control_s: float,
        p0_m: npt.ArrayLike,
        v0_m_per_s: npt.ArrayLike = (0.0, 0.0),
        t0_s: float = 0.0,
    ) -> None:
        if not (math.isfinite(dt_control_s) and dt_control_s > 0.0):
            raise ModelInputError(f"dt_control_s must be finite and > 0, got {dt_control_s!r}")
        y = np.concatenate([np.asarray(p0_m, dtype=np.float64), np.asarray(v0_m_per_s, dtype=np.float64)])
        if y.shape != (4,) or not np.all(np.isfinite(y)):
            raise ModelInputError(f"initial state must be finite (2,) + (2,), got {p0_m!r}, {v0_m_per_s!r}")
        self.physics = physics
        self.integrator = integrator  # and its packed vector (the setter)
        self.p = packed_params(physics)
        self._dt = float(dt_control_s)
        self._t0 = float(t0_s)
        self._k = 0
        self._y = y
        self._contact = np.zeros(4)
        self._g = np.zeros(2)
        self._zero = np.zeros(2)
        self._h = integrator.max_step_s
        self._forces = np.empty((8, 2))
        self._work, self._fbuf, self._sc = new_workspace(2)  # integrator scratch, allocated once
        self.stats = np.zeros(4, dtype=np.int64)  # accepted, rejected, rhs evaluations, forced steps

    @property
    def integrator(self) -> IntegratorParams:
        """Integrator settings; setting them takes effect from the next step."""
        return self._integrator

    @integrator.setter
    def integrator(self, value: IntegratorParams) -> None:
        self._integrator = value
        self._ig = integrator_vector(value)

    @property
    def geom(self) -> Any:
        """The vessel the integrator flies the bead in (:mod:`vesselbot_ros.physics.integrator`'s geometry edge):
        the packed parameters ``p`` of a straight vessel or a planar network."""
        return self.p

    @property
    def t_s(self) -> float:
        """Current tick time (s)."""
        return self._t0 + self._k * self._dt

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(4,) copy of ``(x, z, vx, vz)`` (m, m/s)."""
        return self._y.copy()

    @property
    def contact_state(self) -> npt.NDArray[np.float64]:
        """(4,) copy of the contact state [phase, delta_max, F_max, delta_0]."""
        return self._contact.copy()

    def output(self, with_forces: bool = False) -> PlantOutput:
        """Ground truth at the current tick (see :class:`PlantOutput`)."""
        t = self.t_s
        y = self._y
        delta, wall = wall_delta_xz(t, y[0], y[1], self.p)
        forces = None
        if with_forces:
            forces_into(t, y[0], y[1], y[2], y[3], self._g[0], self._g[1], self._contact, self.p, self._forces)
            forces = self._forces.copy()
        return PlantOutput(t, y[:2].copy(), y[2:].copy(), float(delta), float(wall), bool(delta > 0.0),
                           int(self._contact[0]), forces)

    def step(self, applied_gradient_T_per_m: npt.ArrayLike) -> None:
        """Integrate ``[t_k, t_{k+1}]`` under the applied gradient (T/m, (2,) in the plane, (3,) in a tree).

        Raises:
            ModelInputError: on a non-finite or wrongly shaped gradient, or if
                the integration fails (step too small, non-finite state).
        """
        d = self._g.shape[0]
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


class PlantSimulator3D(PlantSimulator):
    """:class:`PlantSimulator` in a 3-D vessel tree: state ``(x, y, z, vx, vy, vz)``, three gradient axes.

    The same ports on 3-vectors (:class:`PlantOutput` with (3,) ``p``, ``v`` and (8, 3) forces); the kernel is
    :mod:`vesselbot_ros.physics.plant3d`.  ``wall`` is +1 when the nearest wall lies above the centre (its inward
    normal points down), else -1, as in the planar network.

    Args:
        physics: True physics parameters (``vessel.network`` a 3-D tree).
        integrator: Integrator settings.
        dt_control_s: Control period (s).
        p0_m: (3,) initial position (m).
        v0_m_per_s: (3,) initial velocity (m/s).
        t0_s: Initial time (s).
    """

    dims = 3

    def __init__(self, physics: PhysicsParams, integrator: IntegratorParams, dt_control_s: float, p0_m: npt.ArrayLike,
                 v0_m_per_s: npt.ArrayLike = (0.0, 0.0, 0.0), t0_s: float = 0.0) -> None:
        if not (math.isfinite(dt_control_s) and dt_control_s > 0.0):
            raise ModelInputError(f"dt_control_s must be finite and > 0, got {dt_control_s!r}")
        y = np.concatenate([np.asarray(p0_m, dtype=np.float64), np.asarray(v0_m_per_s, dtype=np.float64)])
        if y.shape != (6,) or not np.all(np.isfinite(y)):
            raise ModelInputError(f"initial state must be finite (3,) + (3,), got {p0_m!r}, {v0_m_per_s!r}")
        self.physics = physics
        self.integrator = integrator  # and its packed vector (the setter)
        self.packed = packed3d(physics)
        self.p = self.packed.p
        self._dt = float(dt_control_s)
        self._t0 = float(t0_s)
        self._k = 0
        self._y = y
        self._contact = np.zeros(4)
        self._g = np.zeros(3)
        self._zero = np.zeros(3)
        self._h = integrator.max_step_s
        self._forces = np.empty((8, 3))
        self._work, self._fbuf, self._sc = new_workspace(3)
        self.stats = np.zeros(4, dtype=np.int64)  # accepted, rejected, rhs evaluations, forced steps

    # t_s, state ((6,): (x, y, z, vx, vy, vz)), contact_state, integrator and step are the planar plant's

    @property
    def geom(self) -> Any:
        """The tree the integrator flies the bead in: ``(p, W, F, fh)`` (:mod:`vesselbot_ros.physics.plant3d`)."""
        k = self.packed
        return (self.p, k.W, k.F, k.fh)

    def output(self, with_forces: bool = False) -> PlantOutput:
        """Ground truth at the current tick (see :class:`PlantOutput`)."""
        t = self.t_s
        y = self._y
        k = self.packed
        s_t = forces3d_at(t, y, self._g, self._contact, self.p, k.W, k.F, k.fh, self._forces, self._sc)
        delta = self.p[I_R] - s_t
        wall = 1.0 if self._sc[2, 2] <= 0.0 else -1.0
        return PlantOutput(t, y[:3].copy(), y[3:].copy(), float(delta), wall, bool(delta > 0.0), int(self._contact[0]),
                           self._forces.copy() if with_forces else None)
