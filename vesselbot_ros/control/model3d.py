"""The controller's and observer's model in a 3-D vessel tree: ``F(X, Z)`` on 3-vectors and its integrator.

The planar model (:mod:`vesselbot_ros.control.model`) on the 3-D plant's kernel
(:mod:`vesselbot_ros.physics.plant3d`): ``F`` is every force but the motive one over the mass, evaluated with
the model's physics (the 5 % blood-velocity error of Section III-C included) at a free contact state;
:meth:`DynamicsModel3D.propagate` integrates ``Xd = Z, Zd = F + u`` carrying a contact state.  The input
matrix is ``B = b I`` with the planar model's ``b`` (the coil's three axes act alike on the bead).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.input_mapping import input_matrix
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import (
    OK,
    IntegratorHolder,
    IntegratorParams,
    failure_message,
    integrate,
    new_workspace,
)
from vesselbot_ros.physics.kernel import I_MASS, I_V_F
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.physics.plant3d import forces3d_at
from vesselbot_ros.vessels.plant_field3d import packed3d, planar_twin

__all__ = ["DynamicsModel3D"]


class DynamicsModel3D(IntegratorHolder):
    """``F(X, Z)`` (3,), ``B`` (3, 3) and a propagator for one parameter set in a 3-D tree.

    Args:
        physics: The model's physics parameters (``vessel.network`` a 3-D tree).
        integrator: Integrator settings for :meth:`propagate`.
        mapping: Input mapping (see :mod:`vesselbot_ros.control.input_mapping`).
    """

    dims = 3

    def __init__(self, physics: PhysicsParams, integrator: IntegratorParams | None = None,
                 mapping: Literal["with_tau_m", "paper_printed"] = "with_tau_m") -> None:
        self.physics = physics
        self.integrator = integrator if integrator is not None else IntegratorParams()
        self.packed = packed3d(physics)
        self.p = self.packed.p
        b = float(input_matrix(planar_twin(physics), mapping)[0, 0])
        self.input_gain = b
        self.input_matrix = b * np.eye(3)
        self._p_scaled = self.p.copy()
        self._free = np.zeros(4)
        self._zero3 = np.zeros(3)
        self._y = np.zeros(6)
        self._h = self.integrator.max_step_s
        self.stats = np.zeros(4, dtype=np.int64)
        self._work, self._fbuf, self._sc = new_workspace(3)

    @property
    def geom(self) -> Any:
        """The tree :meth:`propagate` integrates in: ``(p, W, F, fh)`` (:mod:`vesselbot_ros.physics.integrator`)."""
        k = self.packed
        return (self.p, k.W, k.F, k.fh)

    def new_contact_state(self) -> npt.NDArray[np.float64]:
        """A fresh (free) contact state array (4,)."""
        return np.zeros(4)

    def F(self, t_s: float, x: npt.NDArray[np.float64], z: npt.NDArray[np.float64],
          flow_scale: float = 1.0) -> npt.NDArray[np.float64]:
        """``F(X, Z)`` (m/s^2), shape (3,), at ``t_s`` (memoryless contact); ``flow_scale`` multiplies ``V_f``."""
        p = self.p
        if flow_scale != 1.0:
            p = self._p_scaled
            p[I_V_F] = self.p[I_V_F] * flow_scale
        y = self._y
        y[0], y[1], y[2], y[3], y[4], y[5] = x[0], x[1], x[2], z[0], z[1], z[2]
        k = self.packed
        forces3d_at(t_s, y, self._zero3, self._free, p, k.W, k.F, k.fh, self._fbuf, self._sc)
        m = p[I_MASS]
        return np.array((self._fbuf[7, 0] / m, self._fbuf[7, 1] / m, self._fbuf[7, 2] / m))

    def propagate(self, t0_s: float, t1_s: float, y: npt.NDArray[np.float64], u_m_per_s2: npt.NDArray[np.float64],
                  contact: npt.NDArray[np.float64]) -> None:
        """Integrate ``Xd = Z, Zd = F + u`` in place over ``[t0_s, t1_s]`` (``y`` (6,), ``u`` (3,) held).

        Raises:
            ModelInputError: the integration failed (step below the minimum or a non-finite state).
        """
        k = self.packed
        code, self._h = integrate(t0_s, t1_s, y, self._zero3, np.asarray(u_m_per_s2, dtype=np.float64), contact,
                                  (self.p, k.W, k.F, k.fh), self._h, self._ig, self.stats, self._work, self._fbuf, self._sc)
        if code != OK:
            raise ModelInputError(failure_message("observer model", t0_s, t1_s, code, y.tolist()))
