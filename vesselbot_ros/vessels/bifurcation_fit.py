"""The paper's bifurcation pipeline on our CFD: profiles across a major bifurcation, fitted by p_r.

Stations (the angle theta of Fig. 6, our reading): the paper's theta runs from
the parent (theta = 0, parabola) through the apex (centreline velocity
cancelling between 25 and 30 deg) into a daughter (back to a parabola at 60 deg).
We map it onto the major bifurcation of ``config/vessels/paper_iiic_artery.yaml``
(node at ``x_node``, apex (carina tip) at ``x_apex``):

* theta in [0, 30]: the vertical section at ``x = x0 + theta/30 (x_apex - x0)``,
  ``x0 = x_node - 1 mm``, across the whole lumen (lowest to highest wall), so the
  section reaches the carina exactly at 30 deg;
* theta in (30, 60]: the section across the upper daughter, perpendicular to its
  axis, from the apex to 2.5 mm further down the daughter at 60 deg.

On each section y in [-1, 1] runs from the lower to the upper wall and u is the
velocity component normal to the section over the parent's inlet centreline
velocity.  :func:`cfd_profile_samples` samples the cached CFD field;
``tools/fit_bifurcation_table.py`` fits p_r at every angle with
:func:`vesselbot_ros.physics.bifurcation.fit_profile_table` and writes the
default table, the samples and the figure.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.vessels.cfd import NetworkField, network_field
from vesselbot_ros.vessels.network import load_network

__all__ = ["THETAS_DEG", "cfd_profile_samples", "field_lookup"]

#: Angles of the sections (deg): the knots of the shipped table.
THETAS_DEG = (0.0, 10.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0)
NETWORK = "paper_iiic_artery"


def field_lookup(f: NetworkField, names: tuple[str, ...], pts: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Bilinear interpolation of fields ``names`` at points (m, 2) -> (len(names), m)."""
    fx = (pts[:, 0] - f.x0_m) / f.h_m
    fz = (pts[:, 1] - f.z0_m) / f.h_m
    i = np.clip(np.floor(fx).astype(int), 0, f.nx - 2)
    j = np.clip(np.floor(fz).astype(int), 0, f.nz - 2)
    tx = np.clip(fx - i, 0, 1)
    tz = np.clip(fz - j, 0, 1)
    out = []
    for n in names:
        g = f.field(n)
        out.append((1 - tx) * (1 - tz) * g[j, i] + tx * (1 - tz) * g[j, i + 1] + (1 - tx) * tz * g[j + 1, i] + tx * tz * g[j + 1, i + 1])
    return np.array(out)


def _section(f: NetworkField, origin: npt.NDArray[np.float64], along: npt.NDArray[np.float64], n_points: int
             ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(y, u) on the lumen interval of the line origin + s along that contains the origin."""
    s = np.linspace(-6e-3, 6e-3, 6001)
    pts = origin + s[:, None] * along
    sd = field_lookup(f, ("sdist",), pts)[0]
    k0 = int(np.argmin(np.abs(s)))
    lo = k0
    while lo > 0 and sd[lo - 1] > 0:
        lo -= 1
    hi = k0
    while hi < len(s) - 1 and sd[hi + 1] > 0:
        hi += 1
    # wall positions to sub-grid accuracy (linear zero crossing of the signed distance)
    s_lo = s[lo] - sd[lo] * (s[lo] - s[lo - 1]) / (sd[lo] - sd[lo - 1])
    s_hi = s[hi] + sd[hi] * (s[hi + 1] - s[hi]) / (sd[hi] - sd[hi + 1])
    y = np.linspace(-1.0, 1.0, n_points)
    q = origin + (0.5 * (s_lo + s_hi) + 0.5 * (s_hi - s_lo) * y)[:, None] * along
    vx, vz = field_lookup(f, ("vx", "vz"), q)
    normal = np.array([along[1], -along[0]])  # along rotated by -90 deg: downstream
    u = vx * normal[0] + vz * normal[1]
    u[[0, -1]] = 0.0  # no slip on the walls themselves
    return y, u


def cfd_profile_samples(n_points: int = 41, blood: BloodParams | None = None
                        ) -> dict[float, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
    """theta_deg -> (y, u) sampled from the CFD field of the III-C network's major bifurcation."""
    net = load_network(NETWORK)
    f = network_field(net, blood or BloodParams())
    by = {b.name: b for b in net.branches}
    up = by["upper"]
    node = np.array([up.x_m[0], up.z_m[0]])
    d = np.array([up.x_m[1] - up.x_m[0], up.z_m[1] - up.z_m[0]])
    d /= np.hypot(*d)
    r_d = up.radius_m[0]
    half = np.arctan2(d[1], d[0])
    apex_dist = r_d / np.sin(half)  # carina tip on the parent axis (symmetric daughters)
    x_apex = node[0] + apex_dist
    x0 = node[0] - 1.0e-3
    out = {}
    for th in THETAS_DEG:
        if th <= 30.0:
            origin = np.array([x0 + th / 30.0 * (x_apex - x0), 0.5 * r_d])
            out[th] = _section(f, origin, np.array([0.0, 1.0]), n_points)
        else:
            s_apex = apex_dist * np.cos(half)
            s = s_apex + (th - 30.0) / 30.0 * 2.5e-3
            origin = node + s * d
            out[th] = _section(f, origin, np.array([-d[1], d[0]]), n_points)
    return out
