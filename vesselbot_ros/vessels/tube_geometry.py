"""The centreline tubes of a vessel network: which tube holds a point, on two axes (x, z) or three (x, y, z).

:class:`NetworkGeometry` holds a network's smoothed centrelines (:func:`~vesselbot_ros.vessels.network.smooth_centreline`)
and answers the tube a point is deepest in (:meth:`~NetworkGeometry.query`, and compiled for one point,
:meth:`~NetworkGeometry.clearance`).  The tubes are not the wall (a lower bound inside a junction): the meshed
wall is (:mod:`vesselbot_ros.geometry.polyline_wall`).  See docs/vessels.md, "Geometry on any axes".
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError
from vesselbot_ros.vessels.network import VesselNetworkParams, _norm, require_planar, smooth_centreline

__all__ = ["NetworkGeometry"]


def _nearest_on_polyline(trees: dict[str, Any], name: str,
                         branch: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]],
                         q: npt.NDArray[np.float64]
                         ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64],
                                    npt.NDArray[np.float64]]:
    """The tube of one branch at points ``q`` (m, 2 or 3): (``r - |q - foot|`` (m,), foot on the centreline (m, d),
    radius there (m,), arc length there (m,)).

    ``branch`` is the branch's (centreline points, radii, arc lengths); ``trees`` caches each branch's
    ``cKDTree`` by ``name``.  The nearest point of the polyline lies on a segment next to the nearest vertex.
    """
    pts, rad, arc = branch
    tree = trees.get(name)
    if tree is None:
        # deferred: scipy.spatial takes ~0.4 s to import; only a distance query on a network pays it
        from scipy.spatial import cKDTree

        tree = trees[name] = cKDTree(pts)
    _d, j = tree.query(q)
    best = np.full(len(q), np.inf)
    foot = np.zeros_like(q)
    rfoot = np.zeros(len(q))
    sfoot = np.zeros(len(q))
    for seg in (np.maximum(j - 1, 0), np.minimum(j, len(pts) - 2)):
        a = pts[seg]
        d = pts[seg + 1] - a
        t = np.clip(((q - a) * d).sum(axis=1) / np.maximum((d * d).sum(axis=1), 1e-300), 0.0, 1.0)
        f = a + t[:, None] * d
        dist = _norm(q - f)
        better = dist < best
        best[better] = dist[better]
        foot[better] = f[better]
        rfoot[better] = (rad[seg] + t * (rad[seg + 1] - rad[seg]))[better]
        sfoot[better] = (arc[seg] + t * (arc[seg + 1] - arc[seg]))[better]
    return rfoot - best, foot, rfoot, sfoot


class NetworkGeometry:
    """Pure geometry of a network on its axes: smoothed centrelines, radii, arc lengths, the centreline tubes.

    One class for the plane and for space: points are (x, z) when ``dims`` is 2 (a planar network; the
    3-D samples' x and z bit for bit) and (x, y, z) when it is 3 (any network, planar or not).

    Args:
        net: The validated network.
        dims: The axis count; default 3 for a network whose file gives ``y_m`` (:attr:`VesselNetworkParams.is_3d`),
            else 2.

    Raises:
        ConfigError: if ``dims`` is 2 and the network leaves the plane y = 0.
    """

    def __init__(self, net: VesselNetworkParams, dims: int | None = None) -> None:
        self.dims = (3 if net.is_3d else 2) if dims is None else int(dims)
        if self.dims not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {dims!r}")
        if self.dims == 2:  # axis count at the geometry's edge: the plane takes planar networks only
            require_planar(net, "NetworkGeometry (the 2-D centreline tubes)")
        self.net = net
        self.branches = {b.name: smooth_centreline(b, net.smoothing, net.sample_spacing_m, self.dims)
                         for b in net.branches}
        self.names = [b.name for b in net.branches]
        self._trees: dict[str, Any] = {}  # scipy.spatial.cKDTree (scipy has no types here)

    @property
    def is_planar(self) -> bool:
        """True if the network lies in the plane y = 0."""
        return self.net.is_planar

    def centreline(self, branch: str) -> npt.NDArray[np.float64]:
        """(n, dims) smoothed centreline samples of ``branch`` (m)."""
        return self._branch(branch)[0]

    def radius(self, branch: str) -> npt.NDArray[np.float64]:
        """(n,) lumen radius at the samples of ``branch`` (m)."""
        return self._branch(branch)[1]

    def arc_length(self, branch: str) -> npt.NDArray[np.float64]:
        """(n,) arc length of the samples of ``branch`` from its first point (m)."""
        return self._branch(branch)[2]

    def length_m(self, branch: str) -> float:
        """Arc length of the smoothed centreline of ``branch`` (m)."""
        return float(self._branch(branch)[2][-1])

    def _branch(self, branch: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        if branch not in self.branches:
            raise ConfigError(f"branch {branch!r} is not a branch of network {self.net.name!r}; branches: {self.names}")
        return self.branches[branch]

    @cached_property
    def bbox(self) -> tuple[float, ...]:
        """(lo, hi) of the lumen on each axis (m): (x_min, x_max, z_min, z_max) in the plane,
        (x_min, x_max, y_min, y_max, z_min, z_max) in space."""
        lo = np.full(self.dims, np.inf)
        hi = -lo
        for pts, r, _s in self.branches.values():
            lo = np.minimum(lo, (pts - r[:, None]).min(axis=0))
            hi = np.maximum(hi, (pts + r[:, None]).max(axis=0))
        return tuple(float(v) for pair in zip(lo, hi) for v in pair)

    def query(self, points_m: npt.ArrayLike) -> dict[str, npt.NDArray[np.float64]]:
        """The centreline tube each point (m, dims) is deepest in, and where along it.

        Returns a dict: ``sdist`` (m,) max over branches of r_b - |p - foot_b| (m, > 0 inside a tube;
        exact away from the junctions, a lower bound of the lumen's in one), ``foot`` (m, dims) nearest
        centreline point of that branch, ``radius`` (m,) and ``diameter`` (m,) there, ``normal`` (m, dims)
        the unit inward normal (towards the foot, +z where the point is on the centreline), ``branch`` (m,)
        index into ``names``, ``arc`` (m,) arc length of the foot (m).
        """
        q = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
        if q.shape[1] != self.dims:
            raise ValueError(f"points_m must be (m, {self.dims}), got shape {q.shape}")
        sd = np.full(len(q), -np.inf)
        foot = np.zeros_like(q)
        rad = np.zeros(len(q))
        br = np.zeros(len(q), dtype=np.int64)
        arc = np.zeros(len(q))
        for k, name in enumerate(self.names):
            s, f, r, a = _nearest_on_polyline(self._trees, name, self.branches[name], q)
            better = s > sd
            sd[better] = s[better]
            foot[better] = f[better]
            rad[better] = r[better]
            br[better] = k
            arc[better] = a[better]
        v = foot - q
        nv = _norm(v)
        ok = nv > 1e-15
        nrm = np.zeros_like(q)
        nrm[ok] = v[ok] / nv[ok, None]
        nrm[~ok, -1] = 1.0
        # outside the lumen the inward normal points to the centreline too (towards the foot)
        return {"sdist": sd, "foot": foot, "radius": rad, "diameter": 2.0 * rad, "normal": nrm, "branch": br,
                "arc": arc}

    @cached_property
    def _flat(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.int64]]:
        """Every branch's smoothed centreline in one set of arrays: (points (n, dims), radius (n,), starts (b + 1,))."""
        parts = [self.branches[n] for n in self.names]
        starts = np.concatenate([[0], np.cumsum([len(p[0]) for p in parts])]).astype(np.int64)
        return (np.ascontiguousarray(np.concatenate([p[0] for p in parts])), np.concatenate([p[1] for p in parts]),
                starts)

    def clearance(self, *point_m: float) -> tuple[float, float]:
        """(signed distance (m, > 0 inside), diameter (m)) at one point, given as ``dims`` coordinates:
        :meth:`query` for a scalar, compiled.

        The same nearest-vertex, two-segment search and the same arithmetic as :meth:`query`, in a few
        microseconds instead of a few hundred (the nodes check every position they receive with it).
        """
        if len(point_m) != self.dims:
            raise ValueError(f"clearance takes {self.dims} coordinates, got {len(point_m)}")
        pts, rad, starts = self._flat
        return _point_clearance(np.array(point_m, dtype=np.float64), pts, rad, starts)

    def signed_distance(self, points_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """(m,) signed distance to the centreline tubes (m), > 0 inside."""
        return self.query(points_m)["sdist"]

    def centreline_path(self, branch_names: list[str]) -> npt.NDArray[np.float64]:
        """(n, dims) concatenated smoothed centreline through ``branch_names`` (m)."""
        parts = [self._branch(n)[0] for n in branch_names]
        return np.concatenate([parts[0]] + [p[1:] for p in parts[1:]])


@numba.njit(cache=True, nogil=True)
def _dist(v):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`_norm` of one vector, compiled (axis count at the geometry's edge: (x, z) or (x, y, z))."""
    if v.shape[0] == 2:
        return math.hypot(v[0], v[1])
    return math.hypot(math.hypot(v[0], v[2]), v[1])


@numba.njit(cache=True, nogil=True)
def _point_clearance(p, pts, rad, starts):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`NetworkGeometry.clearance`: per branch the polyline point nearest ``p`` on the two segments
    next to its nearest vertex; the branch of the largest signed distance (radius at the foot minus distance)."""
    d = p.shape[0]
    best_s = -np.inf
    best_r = 0.0
    v = np.empty(d)
    for b in range(len(starts) - 1):
        lo, hi = starts[b], starts[b + 1]
        j = lo
        dmin = np.inf
        for i in range(lo, hi):
            d2 = 0.0
            for k in range(d):
                dk = pts[i, k] - p[k]
                d2 += dk * dk
            if d2 < dmin:
                dmin = d2
                j = i
        dist = np.inf
        r = 0.0
        for seg in (max(j - 1, lo), min(j, hi - 2)):
            num = 0.0
            den = 0.0
            for k in range(d):
                dk = pts[seg + 1, k] - pts[seg, k]
                num += (p[k] - pts[seg, k]) * dk
                den += dk * dk
            t = min(max(num / max(den, 1e-300), 0.0), 1.0)
            for k in range(d):
                v[k] = p[k] - (pts[seg, k] + t * (pts[seg + 1, k] - pts[seg, k]))
            dd = _dist(v)
            if dd < dist:
                dist = dd
                r = rad[seg] + t * (rad[seg + 1] - rad[seg])
        if r - dist > best_s:
            best_s = r - dist
            best_r = r
    return best_s, 2.0 * best_r
