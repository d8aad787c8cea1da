"""A network's or a tree's wall as the planner rests a bead on it: the floor below a point, and a bead snapped onto it.

The straight vessel has one lower wall at ``z = -D(t)/2``
(:func:`vesselbot_ros.analysis.plan.wall_rest`).  A planar network or a 3-D
tree has a meshed wall whose nearest facet gives the centre's signed distance
``s_t`` and the inward normal ``n`` (:func:`~vesselbot_ros.physics.integrator.wall_frames`,
the plant's own geometry), and which the eq. (13) pulsation moves by
``-eps(t) D n / 2``.  A bead rests on it where its centre is ``r + L0`` from
it (its radius and one brush length: where the steric force starts): the
*resting surface*, which moves with the wall.

* :meth:`MeshedWall.floor_below` drops a point vertically (``-z``, gravity's
  axis on every shipped vessel) onto the resting surface of the still wall:
  the anchor of a reference that rests on the floor below the route
  (``reference.wall_follow`` 1 then moves it with the wall).
* :meth:`MeshedWall.snap` finds the points of a reference at or beyond the
  resting surface at their times, and puts them on it, moving with the wall
  along its normal: where the planner evaluates the need of a bead on the wall.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from vesselbot_ros.physics.integrator import floor_offsets, wall_frames
from vesselbot_ros.physics.kernel import I_D_PULSE, I_OMEGA_F, I_PHI_F
from vesselbot_ros.sim.scenario import Scenario
from vesselbot_ros.vessels.tree_field import packed_vessel, vessel_geom

__all__ = ["MeshedWall", "Snapped", "need_on", "FLOOR_MIN_UP", "REST_REACH_RADII", "SNAP_ITERATIONS"]

#: How many times the vertical bracket of a point's move onto the resting surface is widened (by one gap) at most.
SNAP_ITERATIONS = 8
#: Bisections of that bracket (a bead-radius bracket to well below a nanometre).
BISECTIONS = 32
#: How far above the resting surface (in bead radii) a point meant to rest on it is still put on it.
REST_REACH_RADII = 0.5
#: The least vertical component of a floor's inward normal (a wall steeper than 78 degrees is not a floor).
FLOOR_MIN_UP = 0.2

Array = npt.NDArray[np.float64]


class Snapped:
    """Points of a reference at their times, those on or beyond the resting surface moved onto it.

    Attributes:
        on_wall: (n,) which points rest on the wall.
        p, v: (n, d) positions and velocities, on the wall where ``on_wall`` (moving with it along its normal).
        normal: (n, d) the wall's unit inward normal at each point (meaningful where ``on_wall``).
    """

    __slots__ = ("normal", "on_wall", "p", "v")

    def __init__(self, on_wall: npt.NDArray[np.bool_], p: Array, v: Array, normal: Array) -> None:
        self.on_wall, self.p, self.v, self.normal = on_wall, p, v, normal


class MeshedWall:
    """The true plant's meshed wall of ``scenario`` (a network or a tree), its pulsation included."""

    def __init__(self, scenario: Scenario) -> None:
        ph = scenario.physics
        if not ph.vessel.network:
            raise ValueError("MeshedWall: a straight vessel's wall is analysis.plan.wall_rest's")
        p, packed = packed_vessel(ph, scenario.dims)
        still = p.copy()
        still[I_D_PULSE] = 0.0
        self.geom = vessel_geom(p, packed)
        self.still = vessel_geom(still, packed)
        self.dims = scenario.dims
        self.gap_m = ph.robot.radius_m + ph.interactions.brush_length_m
        self.brush_m = ph.interactions.brush_length_m
        self.pulsation = float(p[I_D_PULSE])
        self.omega = float(p[I_OMEGA_F])
        self.phase = float(p[I_PHI_F])

    def eps(self, t: Array) -> tuple[Array, Array]:
        """``(eps(t), d eps / dt)`` of eq. (13)."""
        arg = self.omega * t + self.phase
        return self.pulsation * np.sin(arg), self.pulsation * self.omega * np.cos(arg)

    def frames(self, t: npt.ArrayLike, points: npt.ArrayLike, still: bool = False) -> tuple[Array, Array, Array]:
        """``(s_t, normals, D_t)`` at each point (n, d) and time (n,) (the still wall's with ``still``)."""
        pts = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=np.float64)))
        ts = np.ascontiguousarray(np.broadcast_to(np.asarray(t, dtype=np.float64), (pts.shape[0],)))
        s, n, d = wall_frames(ts, pts, self.still if still else self.geom)
        return np.asarray(s), np.asarray(n), np.asarray(d)

    def floor_below(self, point: npt.ArrayLike, press_m: float = 0.0) -> Array | None:
        """The point dropped vertically onto the still wall's resting surface, then ``press_m`` into the wall along
        its normal; ``None`` where no floor lies within a lumen's diameter below, the wall met is no floor (its
        normal's vertical component at most :data:`FLOOR_MIN_UP`) or the point is outside."""
        q = np.asarray(point, dtype=np.float64).copy()
        s0, _, d0 = self.frames(0.0, q, still=True)
        if not s0[0] > self.gap_m:
            return None
        down = np.zeros(self.dims)
        down[-1] = -1.0

        def clearance(lam: float) -> float:
            return float(self.frames(0.0, q + lam * down, still=True)[0][0]) - self.gap_m

        lo, hi, step_m = 0.0, 0.0, max(0.05 * float(d0[0]), 1e-6)
        while clearance(hi) > 0.0:
            lo, hi = hi, hi + step_m
            if hi > 2.0 * float(d0[0]):
                return None
        for _ in range(60):  # to well below a nanometre
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if clearance(mid) > 0.0 else (lo, mid)
        p = q + lo * down
        _, n, _ = self.frames(0.0, p, still=True)
        if not n[0][-1] > FLOOR_MIN_UP:
            return None  # an overhang or a wall steeper than a floor (a side branch's mouth): nothing to rest on
        return p - press_m * n[0]

    def follow_offset(self, points: npt.ArrayLike) -> Array:
        """``D n / 2`` of the still floor below each point (n, d) (:func:`~vesselbot_ros.physics.integrator.floor_offsets`):
        a ``wall_follow`` point moves by ``-eps`` times it, as the reference does."""
        pts = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=np.float64)))
        return np.asarray(floor_offsets(pts, self.still))

    def snap(self, t: npt.ArrayLike, p: npt.ArrayLike, v: npt.ArrayLike,
             resting: npt.NDArray[np.bool_] | None = None) -> Snapped:
        """The points (n, d) at times (n,) with velocities (n, d), those within ``r + L0`` of the wall (or beyond it)
        put on the resting surface, with the wall's normal velocity there.  ``resting`` (n,): points meant to rest
        on the wall (a reference's ``wall_follow`` weight 1), put on it from up to :data:`REST_REACH_RADII` bead
        radii above it too (where the local diameter changes fast, in a junction, the reference's wall-follow
        misses the pulsating wall by tens of micrometres: the bead rests on the wall, not at the reference)."""
        ts = np.atleast_1d(np.asarray(t, dtype=np.float64))
        p = np.array(np.atleast_2d(p), dtype=np.float64)
        v = np.array(np.atleast_2d(v), dtype=np.float64)
        s, n, _d_t = self.frames(ts, p)
        on = s <= self.gap_m + 1e-9
        if resting is not None:
            on |= resting & (s <= self.gap_m + REST_REACH_RADII * (self.gap_m - self.brush_m))
        if np.any(on):
            p[on] = self._onto_surface(ts[on], p[on], s[on], n[on])
            _s_on, n_on, d_on = self.frames(ts[on], p[on])
            n[on] = n_on
            e, de = self.eps(ts[on])
            wall_speed = -0.5 * d_on / (1.0 + e) * de  # the wall moves by -eps D n / 2: its velocity along n
            v[on] += (wall_speed - (v[on] * n_on).sum(axis=1))[:, None] * n_on
        return Snapped(on, p, v, n)

    def _onto_surface(self, ts: Array, p: Array, s: Array, n: Array) -> Array:
        """The points moved onto the resting surface (``s_t = r + L0``) at their times, into the lumen from below it,
        out of it from above: vertically off a floor or a ceiling (not along the nearest facet's normal: at a
        crest or in a junction the nearest facet changes on the way, and its normal points off the surface), along
        the normal off a wall steeper than a floor."""
        vertical = np.abs(n[:, -1]) > FLOOR_MIN_UP
        up = n.copy()
        up[vertical] = 0.0
        up[vertical, -1] = np.sign(n[vertical, -1])
        below = s <= self.gap_m
        reach = max(self.gap_m, 1e-6)
        lo = np.where(below, 0.0, -reach)[:, None] * up  # lo: in the wall's side of the surface (s <= gap)
        hi = np.where(below, reach, 0.0)[:, None] * up   # hi: in the lumen's (s > gap)
        for _ in range(SNAP_ITERATIONS):  # widen until the bracket holds (a point deep in the wall, far above)
            s_lo = self.frames(ts, p + lo)[0]
            s_hi = self.frames(ts, p + hi)[0]
            bad_lo, bad_hi = s_lo > self.gap_m, s_hi <= self.gap_m
            if not (np.any(bad_lo) or np.any(bad_hi)):
                break
            lo[bad_lo] -= reach * up[bad_lo]
            hi[bad_hi] += reach * up[bad_hi]
        for _ in range(BISECTIONS):
            mid = 0.5 * (lo + hi)
            above = self.frames(ts, p + mid)[0] > self.gap_m
            hi = np.where(above[:, None], mid, hi)
            lo = np.where(above[:, None], lo, mid)
        return p + hi


def need_on(model_f, t: Array, snapped: Snapped, a: Array) -> Array:  # type: ignore[no-untyped-def]  # model_f: DynamicsModel.F
    """``|a - F|`` at each snapped point, the wall's share removed where it rests: the contact carries any push
    along the inward normal (the component of ``a - F`` along ``n`` counts only when it points into the wall)."""
    out = np.empty(t.shape)
    for k in range(t.size):
        c = a[k] - model_f(float(t[k]), snapped.p[k], snapped.v[k])
        if snapped.on_wall[k]:
            cn = float((c * snapped.normal[k]).sum())  # not np.dot: its BLAS ddot sums by CPU kernel
            if cn > 0.0:
                c = c - cn * snapped.normal[k]
        out[k] = math.hypot(*c)
    return out
