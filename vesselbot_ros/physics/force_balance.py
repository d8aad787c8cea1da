"""Force balance of eq. (1): every term separately, numpy API over the kernel.

``force_terms`` validates its inputs and calls the numba kernel
(:func:`vesselbot_ros.physics.kernel.forces_into`), so the plant, the force
breakdown message and the figures all use the very same formulas.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics import kernel
from vesselbot_ros.physics._validate import finite_array, finite_vector
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.physics.wall_contact import ContactState
from vesselbot_ros.physics.wall_contact import update_contact_state as _update_contact_state

__all__ = ["ForceTerms", "ContactState", "force_terms", "update_contact_state", "robot_mass"]


class ForceTerms(NamedTuple):
    """Every force of eq. (1) on the robot, in frame W (x along the vessel, z up).

    Attributes:
        magnetic: (2,) bead-pulling force tau_m V M grad_B (N).
        drag: (2,) hydrodynamic drag, eq. (11) (N).
        apparent_weight: (2,) V (rho - rho_f) g, eq. (14) (N).
        contact: (2,) Hertz contact force, eqs. (15)-(16) (N).
        van_der_waals: (2,) eq. (18), both walls (N).
        electrostatic: (2,) eq. (19) (model per config), both walls (N).
        steric: (2,) eq. (22), both walls (N).
        total: (2,) sum of all the above (N).
        delta_m: Signed distance to the nearest wall (m), > 0 in contact (in a network: r - s_t, the
            meshed wall's exact distance with the pulsation).
        wall: +1 upper wall, -1 lower wall (the nearest one; in a network, +1 if its inward normal points down).
        normal_W: (2,) outward normal n of the nearest wall (-), from the robot towards the wall.
        v_fluid_W: (2,) blood velocity at the robot centre (m/s), both components in a network.
        diameter_m: Vessel diameter D(t) (m); in a network the local one at the robot.
    """

    magnetic: npt.NDArray[np.float64]
    drag: npt.NDArray[np.float64]
    apparent_weight: npt.NDArray[np.float64]
    contact: npt.NDArray[np.float64]
    van_der_waals: npt.NDArray[np.float64]
    electrostatic: npt.NDArray[np.float64]
    steric: npt.NDArray[np.float64]
    total: npt.NDArray[np.float64]
    delta_m: float
    wall: int
    normal_W: npt.NDArray[np.float64]
    v_fluid_W: npt.NDArray[np.float64]
    diameter_m: float

    def without_motive(self) -> npt.NDArray[np.float64]:
        """(2,) total minus the magnetic term (N): the load F_tot of Section III-A."""
        return self.total - self.magnetic


def force_terms(
    t_s: float,
    p_W: npt.ArrayLike,
    v_W: npt.ArrayLike,
    gradient_T_per_m: npt.ArrayLike,
    contact: ContactState,
    params: PhysicsParams,
    *,
    packed: npt.NDArray[np.float64] | None = None,
) -> ForceTerms:
    """Evaluate every force term at one state.

    Args:
        t_s: Time t (s).
        p_W: (2,) robot centre (x, z) in W (m).
        v_W: (2,) robot velocity (m/s).
        gradient_T_per_m: (2,) applied gradient (dB/dx, dB/dz) (T/m).
        contact: Caller-held Hertz state for the nearest wall.
        params: Physics parameters.
        packed: The kernel's vector of ``params`` (default ``kernel.pack_params(params)``); a network
            vessel's, its CFD field packed in, comes from :func:`vesselbot_ros.vessels.cfd.packed_params`.

    Returns:
        The :class:`ForceTerms` breakdown.

    Raises:
        ModelInputError: wrong shape or non-finite input.
        ConfigError: a network vessel without ``packed``.
    """
    t = float(finite_array("t_s", t_s))
    p = finite_vector("p_W", p_W)
    v = finite_vector("v_W", v_W)
    g = finite_vector("gradient_T_per_m", gradient_T_per_m)
    if not isinstance(contact, ContactState):
        raise ModelInputError(f"contact must be a ContactState, got {type(contact).__name__}")
    if packed is None:
        packed = kernel.pack_params(params)
    out = np.empty((8, 2))
    kernel.forces_into(t, p[0], p[1], v[0], v[1], g[0], g[1], contact.to_array(), packed, out)
    rows = [out[i].copy() for i in range(8)]
    if packed[kernel.I_NET_ON] > 0.5:
        # a network: the meshed wall's exact distance and normal, the local diameter and the 2-D blood
        # velocity at (x, z), as _forces_network used them (the straight vessel's would be wrong here)
        _s_t, nx, nz, d_t, _eta, vfx, vfz = kernel.network_geometry(t, p[0], p[1], packed)
        delta, wall = kernel.wall_delta_xz(t, p[0], p[1], packed)
        # the ignore below: *rows fills exactly the eight force fields (out has 8 rows), which mypy cannot count
        return ForceTerms(*rows, delta_m=float(delta), wall=int(wall), normal_W=np.array([-float(nx), -float(nz)]),  # type: ignore[misc]  # 8 rows
                          v_fluid_W=np.array([float(vfx), float(vfz)]), diameter_m=float(d_t))
    delta, wall = kernel.nearest_wall_delta(t, p[1], packed)
    d_t = kernel.diameter_at(t, packed)
    vf = kernel.fluid_velocity_x(t, p[0], p[1], packed)
    return ForceTerms(*rows, delta_m=float(delta), wall=int(wall), normal_W=np.array([0.0, float(wall)]),  # type: ignore[misc]  # 8 rows
                      v_fluid_W=np.array([float(vf), 0.0]), diameter_m=float(d_t))


def update_contact_state(state: ContactState, delta_m: float, params: PhysicsParams) -> ContactState:
    """Pure loading/unloading update of ``state`` after observing ``delta_m`` (m).

    Uses the same transition function as the kernel's ``update_contact``.
    """
    packed = kernel.pack_params(params)
    d = min(float(finite_array("delta_m", delta_m)), params.robot.radius_m)
    return _update_contact_state(state, d, float(packed[kernel.I_HERTZ_K]), params.wall.permanent_deformation_ratio)


def robot_mass(params: PhysicsParams) -> float:
    """m = rho V (kg) with rho = tau_m rho_m + (1 - tau_m) rho_poly."""
    return params.robot.mass_kg
