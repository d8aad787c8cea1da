"""The controller's and observer's dynamics model: ``F(X, Z)`` and its integrator, on the vessel's axes.

``F`` is eq. (23)'s drift: every force but the motive one, divided by the mass, from the physics kernel evaluated
with the *model's* parameters, which may differ from the plant's (e.g. the 5 % blood-velocity error of Section
III-C).  The vessel decides the axis count as it does for the plant: a straight vessel or a planar network gives
the plane (x, z), a 3-D tree gives (x, y, z) (:attr:`DynamicsModel.geom`, the integrator's geometry edge).

The contact term needs the Hertz loading/unloading history.  :meth:`DynamicsModel.F` (used by the controller) is
memoryless: it evaluates the loading branch (15) from a free state.  :meth:`DynamicsModel.propagate` (used by the
observer's prediction) carries a contact state along the estimated trajectory, exactly as the plant does.

The input matrix is ``B`` with ``U = B G`` (:mod:`vesselbot_ros.scanner.input_mapping`); in a tree ``B = b I`` with
the plane's ``b`` (the coil's three axes act alike on the bead).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.compiled_stage import model_f_into
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import (
    OK,
    IntegratorHolder,
    IntegratorParams,
    failure_message,
    integrate,
    new_workspace,
)
from vesselbot_ros.physics.kernel import I_V_F
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.scanner.input_mapping import input_matrix
from vesselbot_ros.vessels.network import network_dims
from vesselbot_ros.vessels.tree_field import packed_vessel, vessel_geom

__all__ = ["DynamicsModel", "BLOOD_VELOCITY_ERROR"]

#: Section III-C's model error: the model's blood velocity is 5 % off the plant's (the scenarios' model physics:
#: 0.02625 against 0.025 m/s); what an estimator of the flow scale may assume it knows at the start.
BLOOD_VELOCITY_ERROR = 0.05


class DynamicsModel(IntegratorHolder):
    """``F(X, Z)``, the input matrix ``B`` and a propagator, for one parameter set, on the vessel's axes.

    Args:
        physics: The model's physics parameters (its vessel gives the axis count :attr:`dims`).
        integrator: Integrator settings for :meth:`propagate`.
        mapping: Input mapping (see :mod:`vesselbot_ros.scanner.input_mapping`).
    """

    def __init__(
        self,
        physics: PhysicsParams,
        integrator: IntegratorParams | None = None,
        mapping: Literal["with_tau_m", "paper_printed"] = "with_tau_m",
    ) -> None:
        self.physics = physics
        self.integrator = integrator if integrator is not None else IntegratorParams()  # and its vector (the setter)
        d = network_dims(physics.vessel.network)
        self.dims = d
        self.p, self.packed = packed_vessel(physics, d)  # a tree in space: the 3-D kernel's packed tree
        if d == 3:  # the coil's three axes act alike on the bead: B = b I with the plane's b
            self.input_matrix = float(input_matrix(physics, mapping)[0, 0]) * np.eye(3)
        else:
            self.input_matrix = input_matrix(physics, mapping)
        self._p_scaled = self.p.copy()
        self._h = self.integrator.max_step_s
        self.stats = np.zeros(4, dtype=np.int64)
        self._work, self._fbuf, self._sc = new_workspace(d)  # integrator scratch, allocated once
        self._free = np.zeros(4)
        self._zero = np.zeros(d)
        self._y = np.zeros(2 * d)

    @property
    def geom(self) -> Any:
        """The vessel :meth:`propagate` integrates in (:mod:`vesselbot_ros.physics.integrator`'s geometry edge): the
        packed parameters of a straight vessel or a planar network, or a tree's ``(p, W, F, fh)``."""
        return vessel_geom(self.p, self.packed)

    def new_contact_state(self) -> npt.NDArray[np.float64]:
        """A fresh (free) contact state array (4,)."""
        return np.zeros(4)

    def F(self, t_s: float, x: npt.NDArray[np.float64], z: npt.NDArray[np.float64],
          flow_scale: float = 1.0) -> npt.NDArray[np.float64]:
        """``F(X, Z)`` (m/s^2), shape (d,), at time ``t_s`` (memoryless contact).

        ``flow_scale`` multiplies the model's centreline blood velocity ``V_f``
        (an observer's estimate of the model's flow error; 1 = the model's own).
        """
        p = self.p
        if flow_scale != 1.0:
            p = self._p_scaled
            p[I_V_F] = self.p[I_V_F] * flow_scale
        f = np.empty(self.dims)
        model_f_into(float(t_s), np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(z, dtype=np.float64),
                     vessel_geom(p, self.packed), self._free, self._fbuf, self._sc, self._y, self._zero, f)
        return f

    def propagate(
        self,
        t0_s: float,
        t1_s: float,
        y: npt.NDArray[np.float64],
        u_m_per_s2: npt.NDArray[np.float64],
        contact: npt.NDArray[np.float64],
    ) -> None:
        """Integrate ``Xd = Z, Zd = F + u`` in place over ``[t0_s, t1_s]``.

        Args:
            t0_s: Start (s).
            t1_s: End (s).
            y: (2 d,) ``(X, Z)`` state, overwritten.
            u_m_per_s2: (d,) input acceleration held over the interval.
            contact: (4,) contact state carried along ``y``, updated.

        Raises:
            ModelInputError: if the integration fails (step below the minimum
                or a non-finite state).
        """
        code, self._h = integrate(t0_s, t1_s, y, self._zero, np.asarray(u_m_per_s2, dtype=np.float64), contact,
                                  self.geom, self._h, self._ig, self.stats, self._work, self._fbuf, self._sc)
        if code != OK:
            raise ModelInputError(failure_message("observer model", t0_s, t1_s, code, y.tolist()))
