"""The 3-D meshed wall as one object: its surface, candidate tree and queries, and the local diameter.

:class:`Wall3D` builds the surface and its candidate tree and answers distance and normal (numpy API over
the compiled query); :func:`local_diameter3d` gives the diameter of the largest ball inscribed in the lumen
touching the wall at a point's nearest wall point (the shrinking ball).  The rule: docs/vessels.md, "The wall geometry", `surface_wall`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.geometry.candidate_tree import CandidateTree, candidate_tree
from vesselbot_ros.geometry.surface import Array, Cap, WallSurface, wall_surface
from vesselbot_ros.geometry.surface_query import brute_force3d, nearest_wall3d, query_points3d

__all__ = ["ball_diameters3d", "local_diameter3d", "Wall3D"]

@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _ball_radius(fx, fy, fz, nx, ny, nz, s, r, d, pbox, pstart, grid, nodes, index, rmax, tol, grow):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The largest radius (m) of a ball through F = (fx, fy, fz) centred along the unit n that fits within ``tol``,
    grown from ``r`` by ``grow``, then shrunk through the wall point nearest the last centre that did not fit
    (docs/vessels.md); ``s``: a radius known to fit."""
    lo = s  # the ball of radius s round the point fits
    hi = np.inf  # the least radius known not to fit
    rn = np.inf  # the largest radius W (the wall point nearest the last centre that did not fit) allows
    for _it in range(200):
        cx = fx + r * nx
        cy = fy + r * ny
        cz = fz + r * nz
        sc, ex, ey, ez = nearest_wall3d(cx, cy, cz, d, pbox, pstart, grid, nodes, index)
        if sc >= r - tol:  # fits
            lo = r
            if r >= rn or r >= rmax:
                break  # W's limit itself fits: the largest
        else:
            hi = r
            # W within r - tol of the centre: a ball through F fits W only up to the root of
            # |F + r n - W| = r - tol
            wx = cx - sc * ex - fx
            wy = cy - sc * ey - fy
            wz = cz - sc * ez - fz
            a = wx * nx + wy * ny + wz * nz
            rn = (wx * wx + wy * wy + wz * wz - tol * tol) / (2.0 * (a - tol)) if a > tol else np.inf
        if hi - lo <= 0.05 * tol:
            break
        if hi == np.inf:
            r = grow * r  # grow until a ball does not fit
        elif lo < rn < hi:
            r = rn
        else:
            r = 0.5 * (lo + hi)  # W says nothing (F off the wall by rounding): bisect
    return lo


@numba.njit(cache=True)
def _ball_diameters(pts, q, d, pbox, pstart, grid, nodes, index, rmax, tol, r0, grow):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    out = np.zeros(pts.shape[0])
    for k in range(pts.shape[0]):
        s = q[k, 0]
        if s <= 0.0:
            continue
        nx = q[k, 1]
        ny = q[k, 2]
        nz = q[k, 3]
        fx = pts[k, 0] - s * nx  # the nearest wall point (along the normal the query gives)
        fy = pts[k, 1] - s * ny
        fz = pts[k, 2] - s * nz
        r = max(r0[k] if r0.size else 2.0 * s, s + tol)
        lo = _ball_radius(fx, fy, fz, nx, ny, nz, s, r, d, pbox, pstart, grid, nodes, index, rmax, tol, grow)
        # At a convex crease (a seam's ridge, a junction's apex: the wall folding into the lumen) the point's
        # nearest wall point is on the crease and the smooth normal is one face's: F above lies off the wall and
        # the ball through it is held by the crease at the point's own radius s.  There the ball through the
        # exact nearest wall point along the exact direction to it (a supporting plane of the crease) counts too.
        sf, _ex, _ey, _ez = nearest_wall3d(fx, fy, fz, d, pbox, pstart, grid, nodes, index)
        if abs(sf) > tol:
            se, ex, ey, ez = nearest_wall3d(pts[k, 0], pts[k, 1], pts[k, 2], d, pbox, pstart, grid, nodes, index)
            if se > 0.0:
                lo = max(lo, _ball_radius(pts[k, 0] - se * ex, pts[k, 1] - se * ey, pts[k, 2] - se * ez, ex, ey, ez,
                                          min(se, s), 2.0 * se, d, pbox, pstart, grid, nodes, index, rmax, tol, 2.0))
        out[k] = 2.0 * lo
    return out


#: The per-point inscribed-ball diameters (compiled; :func:`local_diameter3d` without the grid and the fill):
#: ``ball_diameters3d(pts (m, 3) m, q (m, 4) their smooth query rows, d, pbox, pstart, grid, nodes, index,
#: rmax m, tol m, r0 (m,) first radii to try (m; empty: 2 s), grow)`` -> (m,) diameters (m), 0 where ``q``'s
#: distance is <= 0 (outside the lumen); radii grow by ``grow`` until one does not fit.
ball_diameters3d = _ball_diameters


def local_diameter3d(surface: WallSurface, tree: CandidateTree, origin_m: npt.ArrayLike, h: float,
                     shape: tuple[int, int, int], tol_m: float = 2e-6) -> Array:
    """(nz, ny, nx) local diameter (m) on the grid of nodes ``origin + h (i, j, k)`` (docs/vessels.md).

    A lumen node's diameter is that of the largest ball inscribed in the lumen touching the wall at the
    node's nearest wall point F, centred on the (smooth) inward normal there: the largest r with
    s(F + r n) >= r - ``tol_m``, by doubling then shrinking through the nearest wall point (docs/vessels.md);
    so a straight branch of radius R reads 2 R to the facets' sag.  Where F lies off the wall (a convex crease:
    the smooth normal is one face's) the ball through the exact nearest wall point along the exact direction
    to it counts too, the larger of the two.  Nodes outside the lumen take the value of the nearest lumen node.

    Args:
        surface: The wall.  tree: Its candidate tree (covering the grid).
        origin_m: (3,) grid origin (m).  h: Node spacing (m).  shape: ``(nz, ny, nx)`` nodes.
        tol_m: Fit tolerance (m) of a ball (the facets are off the smooth wall by ~1 um).

    Raises:
        ValueError: No node lies in the lumen.
    """
    from scipy.ndimage import distance_transform_edt  # deferred: scipy.ndimage is heavy, needed only to sample

    nz, ny, nx = shape
    o = np.asarray(origin_m, dtype=np.float64)
    Z, Y, X = np.meshgrid(o[2] + h * np.arange(nz), o[1] + h * np.arange(ny), o[0] + h * np.arange(nx), indexing="ij")
    pts = np.ascontiguousarray(np.column_stack([X.ravel(), Y.ravel(), Z.ravel()]))
    args = (surface.data, surface.patch_box, surface.patch_start, tree.grid, tree.nodes, tree.index)
    q = query_points3d(pts, *args, True)
    span = float(np.ptp(surface.wall_vertices(), axis=0).max())
    diam = _ball_diameters(pts, q, *args, 2.0 * span, tol_m, np.zeros(0), 2.0)
    out = diam.reshape(nz, ny, nx)
    empty = out <= 0.0
    if empty.all():
        raise ValueError("local_diameter3d: no grid node lies in the lumen")
    if empty.any():
        _dist, ind = distance_transform_edt(empty, return_indices=True)
        out = out[tuple(ind)]
    return out


class Wall3D:
    """A 3-D meshed wall with its candidate tree (numpy API over the compiled queries).

    Args:
        vertices, triangles, caps, crease_deg, vertex_normals: As :func:`wall_surface`.
        margin_m: Margin (m) of the candidate tree around the wall; the extensions reach 2 (R + margin) past
            each cap (R: the largest cap radius).
        root_m, max_leaf, max_depth, near_m, deep_leaf_m, far_out_m, box_m: As :func:`candidate_tree`.
        patch_m: As :func:`wall_surface`.
    """

    def __init__(self, vertices: npt.ArrayLike, triangles: npt.ArrayLike, caps: Sequence[Cap], margin_m: float = 1.2e-3,
                 crease_deg: float = 30.0, vertex_normals: npt.ArrayLike | None = None, root_m: float = 0.8e-3,
                 max_leaf: int = 8, max_depth: int = 2, patch_m: float = 0.25e-3, near_m: float = math.inf,
                 deep_leaf_m: float = 0.0, far_out_m: float = math.inf,
                 box_m: tuple[npt.ArrayLike, npt.ArrayLike] | None = None) -> None:
        rmax = max(float(c[2]) for c in caps)
        #: The oriented wall and its extensions.
        self.surface = wall_surface(vertices, triangles, caps, 2.0 * (rmax + margin_m) + root_m, crease_deg,
                                    vertex_normals, patch_m)
        #: Its candidate tree.
        self.tree = candidate_tree(self.surface, margin_m, root_m, max_leaf, max_depth, near_m=near_m,
                                   deep_leaf_m=deep_leaf_m, far_out_m=far_out_m, box_m=box_m)
        self._args = (self.surface.data, self.surface.patch_box, self.surface.patch_start, self.tree.grid,
                      self.tree.nodes, self.tree.index)

    def query(self, points_m: npt.ArrayLike, smooth: bool = True) -> dict[str, Array]:
        """``sdist`` (m,) m (> 0 inside) and ``normal`` (m, 3) unit inward normal at points (m, 3) (m).

        ``smooth``: the smooth normal (:func:`smooth_wall3d`); else the exact ``(q - foot)`` one.
        """
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(points_m, dtype=np.float64)))
        r = query_points3d(q, *self._args, bool(smooth))
        return {"sdist": r[:, 0], "normal": r[:, 1:4]}

    def brute_force(self, points_m: npt.ArrayLike, smooth: bool = True) -> dict[str, Array]:
        """:meth:`query` over every triangle (the candidate tree's reference)."""
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(points_m, dtype=np.float64)))
        r = brute_force3d(q, self.surface.data, bool(smooth))
        return {"sdist": r[:, 0], "normal": r[:, 1:4]}

    def local_diameter(self, origin_m: npt.ArrayLike, h: float, shape: tuple[int, int, int]) -> Array:
        """(nz, ny, nx) local diameter (m) on a grid (:func:`local_diameter3d`)."""
        return local_diameter3d(self.surface, self.tree, origin_m, h, shape)
