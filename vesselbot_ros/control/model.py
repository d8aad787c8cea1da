"""The controller's and observer's dynamics model: ``F(X, Z)`` and its integrator.

``F`` is eq. (23)'s drift: every force but the motive one, divided by the
mass, from the physics kernel (:func:`~vesselbot_ros.physics.kernel.accel_no_motive`)
evaluated with the *model's* parameters, which may differ from the plant's
(e.g. the 5 % blood-velocity error of Section III-C).

The contact term needs the Hertz loading/unloading history.  :meth:`F` (used
by the controller) is memoryless: it evaluates the loading branch (15) from a
free state.  :meth:`propagate` (used by the observer's prediction) carries a
contact state along the estimated trajectory, exactly as the plant does.
"""

from __future__ import annotations

from typing import Literal

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
from vesselbot_ros.physics.kernel import I_V_F, accel_no_motive
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.vessels.cfd import packed_params

__all__ = ["DynamicsModel", "BLOOD_VELOCITY_ERROR"]

#: Section III-C's model error: the model's blood velocity is 5 % off the plant's (the scenarios' model physics:
#: 0.02625 against 0.025 m/s); what an estimator of the flow scale may assume it knows at the start.
BLOOD_VELOCITY_ERROR = 0.05


class DynamicsModel(IntegratorHolder):
    """``F(X, Z)``, the input matrix ``B`` and a propagator, for one parameter set.

    Args:
        physics: The model's physics parameters.
        integrator: Integrator settings for :meth:`propagate`.
        mapping: Input mapping (see :mod:`vesselbot_ros.control.input_mapping`).
    """

    def __init__(
        self,
        physics: PhysicsParams,
        integrator: IntegratorParams | None = None,
        mapping: Literal["with_tau_m", "paper_printed"] = "with_tau_m",
    ) -> None:
        self.physics = physics
        self.integrator = integrator if integrator is not None else IntegratorParams()  # and its vector (the setter)
        self.p = packed_params(physics)
        self.input_matrix = input_matrix(physics, mapping)
        self._free = np.zeros(4)
        self._p_scaled = self.p.copy()
        self._h = self.integrator.max_step_s
        self.stats = np.zeros(4, dtype=np.int64)
        self._work, self._fbuf, self._sc = new_workspace(2)  # integrator scratch, allocated once
        self._zero = np.zeros(2)

    @property
    def geom(self) -> npt.NDArray[np.float64]:
        """The vessel :meth:`propagate` integrates in (:mod:`vesselbot_ros.physics.integrator`'s geometry edge): the
        packed parameters of a straight vessel or a planar network."""
        return self.p

    def new_contact_state(self) -> npt.NDArray[np.float64]:
        """A fresh (free) contact state array (4,)."""
        return np.zeros(4)

    def F(self, t_s: float, x: npt.NDArray[np.float64], z: npt.NDArray[np.float64],
          flow_scale: float = 1.0) -> npt.NDArray[np.float64]:
        """``F(X, Z)`` (m/s^2), shape (2,), at time ``t_s`` (memoryless contact).

        ``flow_scale`` multiplies the model's centreline blood velocity ``V_f``
        (an observer's estimate of the model's flow error; 1 = the model's own).
        """
        p = self.p
        if flow_scale != 1.0:
            p = self._p_scaled
            p[I_V_F] = self.p[I_V_F] * flow_scale
        ax, az = accel_no_motive(t_s, x[0], x[1], z[0], z[1], self._free, p)
        return np.array((ax, az))

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
            y: (4,) ``(X, Z)`` state, overwritten.
            u_m_per_s2: (2,) input acceleration held over the interval.
            contact: (4,) contact state carried along ``y``, updated.

        Raises:
            ModelInputError: if the integration fails (step below the minimum
                or a non-finite state).
        """
        code, self._h = integrate(t0_s, t1_s, y, self._zero, np.asarray(u_m_per_s2, dtype=np.float64), contact, self.p,
                                  self._h, self._ig, self.stats, self._work, self._fbuf, self._sc)
        if code != OK:
            raise ModelInputError(failure_message("observer model", t0_s, t1_s, code, y.tolist()))
