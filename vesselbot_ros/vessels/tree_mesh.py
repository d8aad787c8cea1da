"""The solid and the wall surface of a vessel tree in 3-D (gmsh OpenCASCADE): its lumen as one fused solid.

:class:`Tree3D` is the input (per branch a name, a parent, centreline points and radii; :func:`tree_from_network`
makes one of a network).  :func:`mesh_tree` fills the solid with tetrahedra for the flow solve
(:mod:`vesselbot_ros.vessels.tree_cfd`); :func:`mesh_wall` meshes its surface finely for the plant's wall.  How the
solid is built and meshed: docs/vessels.md, "CFD in 3-D".
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError
from vesselbot_ros.vessels.network import VesselNetworkParams, smooth_centreline

__all__ = [
    "Branch3D",
    "Tree3D",
    "Meshed3D",
    "WallMesh3D",
    "tree_from_network",
    "mesh_tree",
    "mesh_wall",
    "local_diameter",
]


@dataclasses.dataclass(frozen=True)
class Branch3D:
    """One branch of a 3-D tree.

    Attributes:
        name: Unique name (used in the outlet's physical group ``outlet:<name>``).
        parent: The parent's name; ``""`` for the inlet branch.
        points_m: Centreline points ``((x, y, z), ...)`` (m), >= 2; a daughter's first point is its
            parent's last point.
        radius_m: Lumen radius at each point (m), or one value for the whole branch.
    """

    name: str
    parent: str
    points_m: tuple[tuple[float, float, float], ...]
    radius_m: tuple[float, ...]

    def points(self) -> npt.NDArray[np.float64]:
        """(n, 3) centreline points (m)."""
        return np.asarray(self.points_m, dtype=np.float64).reshape(-1, 3)

    def radii(self) -> npt.NDArray[np.float64]:
        """(n,) radius at each point (m)."""
        return np.broadcast_to(np.asarray(self.radius_m, dtype=np.float64), (len(self.points_m),)).copy()


@dataclasses.dataclass(frozen=True)
class Tree3D:
    """A vessel tree in 3-D: a name and its branches (any order, exactly one root)."""

    name: str
    branches: tuple[Branch3D, ...]

    def __post_init__(self) -> None:
        names = [b.name for b in self.branches]
        roots = [b.name for b in self.branches if b.parent == ""]
        if len(roots) != 1:
            raise ConfigError(f"3-D tree {self.name!r}: exactly one branch must have parent '', got {roots}")
        for b in self.branches:
            if len(b.points_m) < 2 or len(b.radius_m) not in (1, len(b.points_m)):
                raise ConfigError(f"3-D tree {self.name!r}: branch {b.name!r} needs >= 2 points and 1 or "
                                  f"{len(b.points_m)} radii, got {len(b.points_m)} points, {len(b.radius_m)} radii")
            if b.parent and b.parent not in names:
                raise ConfigError(f"3-D tree {self.name!r}: branch {b.name!r} has unknown parent {b.parent!r}")

    @property
    def root(self) -> Branch3D:
        """The inlet branch."""
        return next(b for b in self.branches if b.parent == "")

    def children(self, name: str) -> list[Branch3D]:
        """Daughters of branch ``name``."""
        return [b for b in self.branches if b.parent == name]

    @property
    def outlets(self) -> list[str]:
        """Names of the branches without daughters, in order."""
        return [b.name for b in self.branches if not self.children(b.name)]


def tree_from_network(net: VesselNetworkParams) -> Tree3D:
    """The network ``net`` as a 3-D tree: each branch's smoothed 3-D centreline (y = 0 for a planar network).

    A straight branch keeps its own points and radii (its centreline is the line; a radius profile
    along it, such as a sinus, is kept point by point).  A curved branch is its smoothed centreline
    (:func:`~vesselbot_ros.vessels.network.smooth_centreline`, sampled every
    ``net.sample_spacing_m``; for a planar branch the x and z of the 2-D solve's centreline bit for
    bit) thinned to about one point per half radius, enough for the mesher's spline to follow it
    to well below a micrometre.
    """
    out = []
    for b in net.branches:
        own = b.points_3d()
        if len(own) == 2 or _collinear(own):
            p3 = tuple((float(x), float(y), float(z)) for x, y, z in own)
            r = b.radii()
        else:
            pts, rad, s = smooth_centreline(b, net.smoothing, net.sample_spacing_m, 3)
            step = max(1, int(0.5 * float(rad.min()) / max(float(s[1] - s[0]), 1e-12)))
            keep = np.unique(np.concatenate([np.arange(0, len(pts), step), [len(pts) - 1]]))
            if len(keep) >= 3 and s[keep[-1]] - s[keep[-2]] < 0.25 * step * (s[1] - s[0]):
                keep = np.delete(keep, -2)  # no sliver of a last segment
            p3 = tuple((float(pts[i, 0]), float(pts[i, 1]), float(pts[i, 2])) for i in keep)
            r = rad[keep]
        radius = (float(r[0]),) if _constant(r) else tuple(float(v) for v in r)
        out.append(Branch3D(b.name, b.parent, p3, radius))
    return Tree3D(net.name, tuple(out))


def _constant(rad: npt.NDArray[np.float64]) -> bool:
    """True if the radii are equal (to 1e-9 of the largest: a file's rounding)."""
    return bool(np.ptp(rad) <= 1e-9 * float(np.max(rad)))


def _collinear(pts: npt.NDArray[np.float64], rel_tol: float = 1e-6) -> bool:
    """True if every point lies on the line through the first and last (to ``rel_tol`` of its length)."""
    d = pts[-1] - pts[0]
    length = float(np.linalg.norm(d))
    if length == 0.0:
        return False
    off = np.cross(pts - pts[0], d / length)
    return bool(np.max(np.linalg.norm(off, axis=1)) <= rel_tol * length + 1e-12)


@dataclasses.dataclass
class Meshed3D:
    """A tetrahedral mesh of a tree.

    Attributes:
        points: (n, 3) vertices (m).  tets: (t, 4) vertex indices.
        boundaries: physical surface name (``inlet``, ``outlet:<branch>``, ``wall``) -> (k, 3) triangles.
        caps: ``inlet`` / ``outlet:<branch>`` -> (centre (3,) m, unit outward normal (3,), radius m).
        elapsed_s: Meshing wall time (s).
    """

    points: npt.NDArray[np.float64]
    tets: npt.NDArray[np.int64]
    boundaries: dict[str, npt.NDArray[np.int64]]
    caps: dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]]
    elapsed_s: float = 0.0


def _unit(v: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return np.asarray(v / np.linalg.norm(v), dtype=np.float64)


@contextlib.contextmanager
def _gmsh_model(name: str, what: str) -> Iterator[Any]:
    """A gmsh session holding one model ``name`` (quiet, one thread); any gmsh error inside becomes one
    ConfigError line naming the tree and ``what`` gmsh could not do; gmsh is finalized on the way out."""
    import gmsh  # deferred: heavy, and its wheel needs libGLU & co (tools/bootstrap.sh checks); only meshing needs it

    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add(name)
        try:
            yield gmsh
        except ConfigError:
            raise
        except Exception as exc:  # noqa: BLE001 - gmsh raises a bare Exception with its last error
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ConfigError(f"3-D tree {name!r}: gmsh could not {what}: {msg}") from None
    finally:
        gmsh.finalize()


def mesh_tree(tree: Tree3D, mesh_size_m: float, wall_elements_per_circle: int) -> Meshed3D:
    """Mesh ``tree`` as one solid (docs/vessels.md, "CFD in 3-D"): linear tetrahedra of at most ``mesh_size_m`` in
    the lumen, ``wall_elements_per_circle`` around every circumference; raises ConfigError if gmsh cannot."""
    t0 = time.perf_counter()
    caps: dict[str, tuple[Any, Any, float]] = {}
    with _gmsh_model(tree.name, "build the mesh") as gmsh:
        volumes, assigned, wall = _lumen(gmsh, tree, caps)
        groups = {k: gmsh.model.addPhysicalGroup(2, v) for k, v in assigned.items()}
        groups["wall"] = gmsh.model.addPhysicalGroup(2, wall)
        for k, g in groups.items():
            gmsh.model.setPhysicalName(2, g, k)
        gmsh.model.setPhysicalName(3, gmsh.model.addPhysicalGroup(3, [volumes[0][1]]), "lumen")
        h = mesh_size_m
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.01 * h)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", wall_elements_per_circle)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        gmsh.option.setNumber("Mesh.Algorithm3D", 1)
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.model.mesh.generate(3)
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        types, _et, enodes = gmsh.model.mesh.getElements(3)
        tets_raw = np.concatenate([np.asarray(en, dtype=np.int64) for ty, en in zip(types, enodes) if ty == 4])
        tris: dict[str, npt.NDArray[np.int64]] = {}
        for k, g in groups.items():
            parts = []
            for s in gmsh.model.getEntitiesForPhysicalGroup(2, g):
                ty2, _e2, en2 = gmsh.model.mesh.getElements(2, int(s))
                parts += [np.asarray(en, dtype=np.int64) for ty, en in zip(ty2, en2) if ty == 2]
            tris[k] = np.concatenate(parts).reshape(-1, 3)
    tags = np.asarray(node_tags, dtype=np.int64)
    xyz = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    lookup = np.full(tags.max() + 1, -1, dtype=np.int64)
    lookup[tags] = np.arange(len(tags))
    tet = lookup[tets_raw.reshape(-1, 4)]
    if len(tet) == 0:
        raise ConfigError(f"3-D tree {tree.name!r}: gmsh produced no tetrahedra")
    used = np.unique(tet)
    remap = np.full(len(tags), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    pts3 = xyz[used]
    tet = remap[tet]
    # positive orientation
    a, b_, c, d = (pts3[tet[:, i]] for i in range(4))
    vol = np.einsum("ij,ij->i", np.cross(b_ - a, c - a), d - a)
    neg = vol < 0
    tet[neg] = tet[neg][:, [0, 2, 1, 3]]
    bnd = {k: remap[lookup[v]] for k, v in tris.items()}
    return Meshed3D(pts3, tet, bnd, _cap_normals(caps, pts3, bnd), time.perf_counter() - t0)


@dataclasses.dataclass
class WallMesh3D:
    """A fine triangulation of a tree's wall (its lumen's boundary without the caps), for the plant.

    Attributes:
        vertices: (n, 3) vertices (m).  triangles: (k, 3) vertex indices (gmsh's orientation).
        caps: ``inlet`` / ``outlet:<branch>`` -> (centre (3,) m, unit outward normal (3,), radius m).
        meta: sizes, the facets' measured sag (um: max and 99th percentile of each triangle's centroid's distance
            to the CAD surface), the meshing time (s).
    """

    vertices: npt.NDArray[np.float64]
    triangles: npt.NDArray[np.int64]
    caps: dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]]
    meta: dict[str, Any]


#: Elements per 2 pi radians of curvature of the curvature sizing :func:`mesh_wall` reads the curvature through.
_CURVATURE_PROBE = 64


def mesh_wall(tree: Tree3D, sag_m: float = 0.5e-6, max_size_m: float = 1.0e-3) -> WallMesh3D:
    """Mesh only the surface of ``tree``'s lumen (the solid :func:`mesh_tree` fills): triangles whose sag off the
    CAD surface is about ``sag_m``.

    Size: gmsh's curvature sizing gives each point its radius of curvature rho (the larger principal curvature:
    around a tube, its radius); a chord c over a radius rho sags c^2 / (8 rho) (c^2 / (6 rho) over a triangle
    whose corners lie on a sphere), so the size is sqrt(6 rho sag_m), at most ``max_size_m`` (a tube of 1.5 mm:
    67 um, 140 around; 4 mm: 110 um).  The caps are meshed (their triangles give their normals) and left out.

    Raises:
        ConfigError: gmsh cannot build the solid or mesh it.
    """
    t0 = time.perf_counter()
    caps: dict[str, tuple[Any, Any, float]] = {}
    with _gmsh_model(tree.name, "mesh the wall") as gmsh:
        _volumes, assigned, wall = _lumen(gmsh, tree, caps)
        gmsh.option.setNumber("Mesh.MeshSizeMax", max_size_m)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.01 * math.sqrt(sag_m * max_size_m))
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", _CURVATURE_PROBE)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
        gmsh.option.setNumber("Mesh.Algorithm", 6)

        def size(_dim: int, _tag: int, _x: float, _y: float, _z: float, lc: float) -> float:
            rho = lc * _CURVATURE_PROBE / (2.0 * math.pi)  # the curvature sizing's lc = 2 pi rho / N
            return min(lc, math.sqrt(6.0 * rho * sag_m))

        gmsh.model.mesh.setSizeCallback(size)
        gmsh.model.mesh.generate(2)
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        tags = np.asarray(node_tags, dtype=np.int64)
        xyz = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
        lookup = np.full(tags.max() + 1, -1, dtype=np.int64)
        lookup[tags] = np.arange(len(tags))

        def triangles(surfaces: list[int]) -> npt.NDArray[np.int64]:
            parts = []
            for sf in surfaces:
                ty, _e, en = gmsh.model.mesh.getElements(2, int(sf))
                parts += [np.asarray(e, dtype=np.int64) for t, e in zip(ty, en) if t == 2]
            return lookup[np.concatenate(parts).reshape(-1, 3)]

        wall_tri = triangles(wall)
        cap_tri = {k: triangles(v) for k, v in assigned.items()}
        sag = []
        for sf in wall:  # each triangle's centroid against its CAD surface
            tri = triangles([sf])
            cen = xyz[tri].mean(axis=1)
            foot, _par = gmsh.model.getClosestPoint(2, int(sf), cen.ravel().tolist())
            sag.append(np.linalg.norm(np.asarray(foot).reshape(-1, 3) - cen, axis=1))
    caps = _cap_normals(caps, xyz, cap_tri)
    used, inv = np.unique(wall_tri, return_inverse=True)
    sags = np.concatenate(sag)
    meta = {"vertices": int(len(used)), "triangles": int(len(wall_tri)), "sag_target_um": sag_m * 1e6,
            "sag_max_um": float(sags.max() * 1e6), "sag_p99_um": float(np.percentile(sags, 99) * 1e6),
            "mesh_s": time.perf_counter() - t0}
    return WallMesh3D(np.ascontiguousarray(xyz[used]), np.ascontiguousarray(inv.reshape(-1, 3).astype(np.int64)), caps, meta)


def _lumen(gmsh: Any, tree: Tree3D, caps: dict[str, tuple[Any, Any, float]]
           ) -> tuple[list[tuple[int, int]], dict[str, list[int]], list[int]]:
    """Build the tree's lumen as one OCC volume in the current gmsh model (docs/vessels.md, "CFD in 3-D": the fuse,
    and the seamless branch-by-branch one if that is not whole); fills ``caps``.

    Returns:
        (the volumes (one), cap name -> its flat surfaces, the wall's surfaces).

    Raises:
        ConfigError: the union is not one volume, or a cap has no flat face.
    """
    occ = gmsh.model.occ
    pieces = _tree_solids(occ, tree, caps)
    vols = [v for piece in pieces for v in piece]
    if len(vols) > 1:
        occ.fuse(vols[:1], vols[1:])
    occ.synchronize()
    if len(pieces) > 1 and not _fused_lumen(gmsh, tree, caps):
        # OpenCASCADE's fuse of all the solids at once can drop a swept tube, and gmsh cannot mesh
        # some trimmed periodic (seamed) pipe walls: again with seamless swept tubes, branch by branch
        gmsh.model.remove()
        gmsh.model.add(tree.name)
        occ = gmsh.model.occ
        pieces = _tree_solids(occ, tree, caps, seamless=True)
        whole = pieces[0]
        for piece in pieces[1:]:
            whole, _map = occ.fuse(whole, piece)
        occ.synchronize()
    volumes = gmsh.model.getEntities(3)
    if len(volumes) != 1:
        raise ConfigError(f"3-D tree {tree.name!r}: the fused tubes make {len(volumes)} volumes, not one "
                          "(branches that do not touch, or an OpenCASCADE boolean failure)")
    assigned, wall = _assign_caps(gmsh, caps)
    missing = [k for k, v in assigned.items() if not v]
    if missing:
        raise ConfigError(f"3-D tree {tree.name!r}: no flat cap found for {missing} after the union "
                          "(an end inside another tube?)")
    return volumes, assigned, wall


def _cap_normals(caps: dict[str, tuple[Any, Any, float]], points: npt.NDArray[np.float64],
                 cap_triangles: dict[str, npt.NDArray[np.int64]]) -> dict[str, tuple[Any, Any, float]]:
    """Each cap's unit outward normal from its own (flat) triangles (OCC's spline ends where the chord-length
    spline does, but its end tangent follows OCC's end conditions, and the swept disc is normal to OCC's curve)."""
    out = {}
    for k, (c, n, r) in caps.items():
        tri = points[cap_triangles[k]]
        nn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(axis=0)
        out[k] = (c, _unit(nn) * (1.0 if float(np.dot(nn, n)) > 0 else -1.0), r)
    return out


def _tree_solids(occ: Any, tree: Tree3D, caps: dict[str, tuple[Any, Any, float]],
                 seamless: bool = False) -> list[list[tuple[int, int]]]:
    """Per branch its OCC volumes (its tube, and its node's sphere if any); fills ``caps``.

    ``seamless``: a swept disc's profile is three arcs, so its wall is three faces, none periodic.
    """
    pieces = []
    for b in tree.branches:
        pts, rad = b.points(), b.radii()
        vols = _branch_solid(occ, pts, rad, seamless)
        if b.parent == "":
            caps["inlet"] = (pts[0].copy(), -_unit(_end_tangent(pts, 0)), float(rad[0]))
        kids = tree.children(b.name)
        if not kids:
            caps[f"outlet:{b.name}"] = (pts[-1].copy(), _unit(_end_tangent(pts, -1)), float(rad[-1]))
        else:
            t_end = _unit(_end_tangent(pts, -1))
            straight_on = any(float(np.dot(_unit(_end_tangent(k.points(), 0)), t_end)) > math.cos(math.radians(1.0))
                              and float(k.radii()[0]) >= float(rad[-1]) * (1 - 1e-9) for k in kids)
            if not straight_on:
                c = pts[-1]
                vols.append((3, occ.addSphere(float(c[0]), float(c[1]), float(c[2]), float(rad[-1]))))
        pieces.append(vols)
    return pieces


def _assign_caps(gmsh: Any, caps: dict[str, tuple[Any, Any, float]]) -> tuple[dict[str, list[int]], list[int]]:
    """The fused volume's boundary surfaces: the flat ones at each cap (by cap name), and the rest (wall)."""
    occ = gmsh.model.occ
    surf = [t for _d, t in gmsh.model.getBoundary(gmsh.model.getEntities(3), oriented=False)]
    assigned: dict[str, list[int]] = {k: [] for k in caps}
    wall: list[int] = []
    for s in surf:
        com = np.array(occ.getCenterOfMass(2, s))
        name = None
        if gmsh.model.getType(2, s) == "Plane":
            for k, (c, _n, r) in caps.items():
                if np.linalg.norm(com - c) < 1e-3 * r:
                    name = k
                    break
        if name is None:
            wall.append(s)
        else:
            assigned[name].append(s)
    return assigned, wall


def _fused_lumen(gmsh: Any, tree: Tree3D, caps: dict[str, tuple[Any, Any, float]]) -> bool:
    """True if the fuse made one volume with a flat face at every cap and every branch's mid-point inside it."""
    volumes = gmsh.model.getEntities(3)
    if len(volumes) != 1:
        return False
    assigned, _wall = _assign_caps(gmsh, caps)
    if not all(assigned.values()):
        return False
    for b in tree.branches:
        pts = b.points()
        mid = pts[len(pts) // 2] if len(pts) > 2 else 0.5 * (pts[0] + pts[-1])
        if not gmsh.model.isInside(3, volumes[0][1], [float(x) for x in mid]):
            return False
    return True


def _end_tangent(pts: npt.NDArray[np.float64], end: int) -> npt.NDArray[np.float64]:
    """Forward tangent at the first (``end`` 0) or last (-1) point: of the end segment, or of the spline's end."""
    if len(pts) == 2 or _collinear(pts):
        return np.asarray(pts[-1] - pts[0], dtype=np.float64)
    spl = _spline(pts)
    s_end = spl.x[-1] if end == -1 else spl.x[0]
    return np.asarray(spl(s_end, 1), dtype=np.float64)


def _spline(pts: npt.NDArray[np.float64]) -> Any:
    """Chord-length cubic spline through ``pts`` (the curve the mesher sweeps along, up to OCC's own parametrisation)."""
    from scipy.interpolate import CubicSpline  # deferred: scipy.interpolate is heavy, needed only for curved branches

    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return CubicSpline(chord, pts, bc_type="natural" if len(pts) >= 4 else "not-a-knot")


def _branch_solid(occ: Any, pts: npt.NDArray[np.float64], rad: npt.NDArray[np.float64],
                  seamless: bool = False) -> list[tuple[int, int]]:
    """OCC volumes of one branch: a cylinder or a cone chain (straight), a swept disc or a loft (curved).

    ``seamless``: the swept disc is bounded by three 120-degree arcs (a wall of three faces, none periodic).
    """
    straight = len(pts) == 2 or _collinear(pts)
    if straight and _constant(rad):
        d = pts[-1] - pts[0]
        return [(3, occ.addCylinder(*map(float, pts[0]), *map(float, d), float(rad[0])))]
    if not straight and _constant(rad):
        ptags = [occ.addPoint(*map(float, p)) for p in pts]
        curve = occ.addSpline(ptags)
        wire = occ.addWire([curve])
        t0 = _unit(_end_tangent(pts, 0))
        e1 = _any_normal(t0)
        if seamless:
            e2 = np.cross(t0, e1)
            centre = occ.addPoint(*map(float, pts[0]))
            ring = [occ.addPoint(*map(float, pts[0] + rad[0] * (math.cos(a) * e1 + math.sin(a) * e2)))
                    for a in (0.0, 2.0 * math.pi / 3.0, 4.0 * math.pi / 3.0)]
            arcs = [occ.addCircleArc(ring[i], centre, ring[(i + 1) % 3]) for i in range(3)]
            disk = occ.addPlaneSurface([occ.addCurveLoop(arcs)])
        else:
            disk = occ.addDisk(*map(float, pts[0]), float(rad[0]), float(rad[0]), zAxis=list(map(float, t0)),
                               xAxis=list(map(float, e1)))
        out = occ.addPipe([(2, disk)], wire, "DiscreteTrihedron")
        return [(d, t) for d, t in out if d == 3]
    if not straight:
        # a curved, tapering branch: a smooth loft through the circles at its points, normal to its spline
        spl = _spline(pts)
        wires = []
        for i, sv in enumerate(spl.x):
            t = _unit(np.asarray(spl(sv, 1), dtype=np.float64))
            circ = occ.addCircle(*map(float, pts[i]), float(rad[i]), zAxis=list(map(float, t)),
                                 xAxis=list(map(float, _any_normal(t))))
            wires.append(occ.addCurveLoop([circ]))
        out = occ.addThruSections(wires, makeSolid=True, makeRuled=False)
        return [(d, t) for d, t in out if d == 3]
    vols = []
    for i in range(len(pts) - 1):
        a, d = pts[i], pts[i + 1] - pts[i]
        if abs(rad[i + 1] - rad[i]) <= 1e-9 * float(rad[i]):  # OCC refuses a cone of equal radii
            vols.append((3, occ.addCylinder(*map(float, a), *map(float, d), float(rad[i]))))
        else:
            vols.append((3, occ.addCone(*map(float, a), *map(float, d), float(rad[i]), float(rad[i + 1]))))
        if 0 < i and not straight:  # a kink: the sphere fills the wedge between the two cones
            vols.append((3, occ.addSphere(*map(float, a), float(rad[i]))))
    return vols


def _any_normal(t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """A unit vector normal to ``t``."""
    e = np.eye(3)[int(np.argmin(np.abs(t)))]
    return _unit(np.cross(t, e))


def local_diameter(tree: Tree3D, points_m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(m,) diameter 2 r_b of the branch whose tube's capsule ``r_b - |x - c_b|`` is largest at each point (m).

    Each branch's centreline is the polyline through its points densified to r/20 (the foot is
    the nearest densified vertex); a spline-swept branch's curve is its chord-length spline.
    """
    from scipy.spatial import cKDTree  # deferred: scipy.spatial is heavy, needed only when a solve sizes its viscosity

    q = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
    best = np.full(len(q), -np.inf)
    diam = np.zeros(len(q))
    for b in tree.branches:
        pts, rad = b.points(), b.radii()
        dense, rdense = _densify(pts, rad, 0.05 * float(rad.min()))
        dist, idx = cKDTree(dense).query(q)
        s = rdense[idx] - dist
        better = s > best
        best[better] = s[better]
        diam[better] = 2.0 * rdense[idx[better]]
    return diam


def _densify(pts: npt.NDArray[np.float64], rad: npt.NDArray[np.float64], step_m: float
             ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    n = max(2, int(math.ceil(chord[-1] / step_m)) + 1)
    s = np.linspace(0.0, chord[-1], n)
    if len(pts) >= 3 and not _collinear(pts):
        dense = _spline(pts)(s)
    else:
        dense = np.column_stack([np.interp(s, chord, pts[:, k]) for k in range(3)])
    return np.asarray(dense, dtype=np.float64), np.interp(s, chord, rad)
