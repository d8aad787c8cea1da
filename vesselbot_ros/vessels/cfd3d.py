"""Steady 3-D blood flow through a vessel tree: gmsh solid mesh + scikit-fem Navier-Stokes.

The 3-D counterpart of :mod:`vesselbot_ros.vessels.cfd` (which solves in the XZ plane and imposes
Murray shares because a planar channel cannot keep the 3-D flux balance).  Here the lumen is a
solid: each branch a tube around its 3-D centreline, fused at the junctions, and the outlets may
be left traction-free so the tree splits the flow by itself.

Input (library-independent, :class:`Tree3D`): per branch a name, a parent (``""`` for the inlet
branch), centreline points ``(n, 3)`` m and radii ``(n,)`` m (or one value).  A daughter starts
at its parent's last point.  :func:`tree_from_network` turns a
:class:`~vesselbot_ros.vessels.network.VesselNetworkParams` into one (its smoothed 3-D centreline;
y = 0 for a planar network).

Mesh (:func:`mesh_tree`, gmsh OpenCASCADE): a branch whose points are collinear is a cylinder, or,
if its radius varies, a chain of truncated cones between its points (the radius linear between
points, as the network format defines it: exact); a curved branch of constant radius is
a disc swept along the interpolating spline through its points (``occ.addPipe``); a curved branch
whose radius varies is a smooth loft through the circles at its points, each normal to the spline
(``occ.addThruSections``).  A node whose daughters all turn away
from the parent gets a sphere of the parent's end radius (the 3-D version of the 2-D solve's
disc) so the tubes join without a gap.  Everything is fused (``occ.fuse``) into one volume;
if that fuse of all the solids at once is not one whole lumen (one volume, a flat face at every
cap, every branch's mid-point inside: OpenCASCADE can drop a swept tube, and gmsh cannot mesh some
trimmed periodic pipe walls -- both seen on ``synthetic_tree_3d``), the solids are built again with
each swept disc bounded by three 120-degree arcs (a wall of three faces, none periodic: the same
surface) and fused branch by branch, in tree order (trees whose one fuse is whole are meshed as
before); physical groups ``inlet``, ``outlet:<branch>``, ``wall`` and ``lumen``.  Linear tetrahedra; the
wall is resolved by ``wall_elements_per_circle`` elements around every circumference (gmsh's
curvature sizing) and the interior by ``mesh_size_m``.

Wall (:func:`mesh_wall`): the surface of the same solid meshed alone, for the 3-D plant's wall, far finer than
the flow needs: sized by the surface's curvature so that a facet sags about ``sag_m`` off the CAD surface
(0.5 um: 67 um triangles on a 1.5 mm tube, 110 um on the carotid's 4 mm one, 0.2-0.45 million triangles for
the shipped trees, 5-30 s), the caps (the solid's flat faces at the branch ends) meshed for their normals and
left out.  The measured sag (each triangle's centroid against the CAD surface) is returned with it.

Equations: ``rho (u . grad) u = -grad p + div(mu grad u)``, ``div u = 0``, Taylor-Hood P2/P1, mu the
Pries viscosity (the blood model) at the local branch diameter, element by element (the diameter of
the branch tube whose capsule ``r - |x - c|`` is largest at the element's centroid, as the 2-D
solve sizes it).  Boundary conditions: Poiseuille inflow ``V_c (1 - (rho/R)^2)`` on the inlet, no
slip on the wall, and either every outlet traction-free (``natural``: ``mu du/dn - p n = 0``, the
"do nothing" condition: equal pressure at fully developed outlets) or (``murray`` / ``area``) a
Poiseuille outflow on every outlet but the widest, each scaled so its *discrete* flux is its share
(r^3 or r^2) of the *discrete* inlet flux (so the imposed shares hold exactly), the widest outlet
traction-free.

Solver: the velocity block is ``I_3 (x) A`` (the viscous and Oseen terms act on each component
alike and every Dirichlet condition holds on all three components), so only a scalar P2 operator
is assembled and one algebraic multigrid hierarchy (pyamg, smoothed aggregation on the viscous
block) serves all three components.  Outer Krylov: flexible GMRES (pyamg.krylov.fgmres) on the
condensed saddle-point system with the block upper-triangular preconditioner
``[[A, -B^T], [0, -M_p(1/mu)]]`` (one V-cycle per component; the pressure mass matrix weighted by
1/mu, its diagonal, for the Schur complement).  Picard (Oseen) iterations from the Stokes
solution until the relative velocity change is below ``picard_tol``; a solve that does not
converge raises :class:`vesselbot_ros.errors.RunError` and nothing is cached.

Results (:class:`FlowSolution3D`): P2 velocity and P1 pressure evaluable at arbitrary points
(:func:`evaluate`), per-cap flow rates, and :func:`sample_grid` (a regular grid with an inside mask
for a trilinear lookup).  :func:`solve_tree_cached` caches a solution on disk by a hash of its
inputs (written atomically; never on failure).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from vesselbot_ros.atomic_io import atomic_open
from vesselbot_ros.config import ConfigError, to_mapping
from vesselbot_ros.errors import RunError
from vesselbot_ros.physics.blood_viscosity import viscosity_for
from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.progress import ProgressFn
from vesselbot_ros.vessels.network import VesselNetworkParams, smooth_centreline

__all__ = [
    "Branch3D",
    "Tree3D",
    "Flow3DSettings",
    "Meshed3D",
    "FlowSolution3D",
    "tree_from_network",
    "settings_from_network",
    "mesh_tree",
    "WallMesh3D",
    "mesh_wall",
    "solve_tree",
    "evaluate",
    "sample_grid",
    "section_flux",
    "local_diameter",
    "cache_dir",
    "solution_key",
    "solve_tree_cached",
]

CACHE_VERSION = 1


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


@dataclasses.dataclass(frozen=True)
class Flow3DSettings:
    """How a 3-D tree is meshed and solved.

    Attributes:
        inlet_centreline_velocity_m_per_s: Centreline velocity of the Poiseuille inflow (m/s).
        mesh_size_m: Largest tetrahedron edge (m), the lumen's interior.
        wall_elements_per_circle: Elements around a circumference of the wall (gmsh curvature
            sizing): the narrow branches' resolution (the polygonal section's area is short of the
            circle's by about (2 pi / N)^2 / 6: 0.64 % at N = 32).
        outlets: ``natural`` (every outlet traction-free), ``murray`` (r^3 shares) or ``area`` (r^2).
        picard_max_iterations: Cap on the Picard (Oseen) iterations.
        picard_tol: Relative change of the velocity (max norm) at which Picard stops.
        linear_tol: Relative residual of each Oseen solve (flexible GMRES).
        linear_max_iterations: Cap on the GMRES iterations of one Oseen solve.
    """

    inlet_centreline_velocity_m_per_s: float = 0.025
    mesh_size_m: float = 3.0e-4
    wall_elements_per_circle: int = 24
    outlets: Literal["natural", "murray", "area"] = "natural"
    picard_max_iterations: int = 30
    picard_tol: float = 1.0e-7
    linear_tol: float = 1.0e-10
    linear_max_iterations: int = 600

    def __post_init__(self) -> None:
        if self.outlets not in ("natural", "murray", "area"):
            raise ConfigError(f"outlets must be one of ['natural', 'murray', 'area'], got {self.outlets!r}")
        for f in ("inlet_centreline_velocity_m_per_s", "mesh_size_m", "picard_tol", "linear_tol"):
            v = getattr(self, f)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{f} must be positive, got {v!r}")
        if self.wall_elements_per_circle < 6:
            raise ConfigError(f"wall_elements_per_circle must be >= 6, got {self.wall_elements_per_circle!r}")


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


def settings_from_network(net: VesselNetworkParams, *, outlets: str | None = None,
                          mesh_size_m: float | None = None, wall_elements_per_circle: int = 32) -> Flow3DSettings:
    """3-D settings from ``net.cfd``: its inlet velocity and Picard cap; outlets ``natural`` unless given.

    The default mesh, 1.2 ``cfd.mesh_size_m`` inside and 32 elements around every circumference, is the
    one measured for ``paper_iiic_artery`` (0.3 mm: 529 293 dofs, about 4 min and 2.4 GB on two cores).
    """
    c = net.cfd
    return Flow3DSettings(inlet_centreline_velocity_m_per_s=c.inlet_centreline_velocity_m_per_s,
                          mesh_size_m=mesh_size_m if mesh_size_m is not None else 1.2 * c.mesh_size_m,
                          wall_elements_per_circle=wall_elements_per_circle,
                          outlets=outlets or "natural",  # type: ignore[arg-type]  # checked by Flow3DSettings
                          picard_max_iterations=c.picard_max_iterations)


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


def mesh_tree(tree: Tree3D, settings: Flow3DSettings) -> Meshed3D:
    """Mesh ``tree`` as one solid (see the module docstring); raises ConfigError if gmsh cannot."""
    t0 = time.perf_counter()
    caps: dict[str, tuple[Any, Any, float]] = {}
    with _gmsh_model(tree.name, "build the mesh") as gmsh:
        volumes, assigned, wall = _lumen(gmsh, tree, caps)
        groups = {k: gmsh.model.addPhysicalGroup(2, v) for k, v in assigned.items()}
        groups["wall"] = gmsh.model.addPhysicalGroup(2, wall)
        for k, g in groups.items():
            gmsh.model.setPhysicalName(2, g, k)
        gmsh.model.setPhysicalName(3, gmsh.model.addPhysicalGroup(3, [volumes[0][1]]), "lumen")
        h = settings.mesh_size_m
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.01 * h)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", settings.wall_elements_per_circle)
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
    """Build the tree's lumen as one OCC volume in the current gmsh model (module docstring: the fuse, and the
    seamless branch-by-branch one if that is not whole); fills ``caps``.

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


@dataclasses.dataclass
class FlowSolution3D:
    """A steady 3-D solution.

    Attributes:
        mesh: skfem MeshTet.  vbasis: scalar P2 basis (each velocity component).  pbasis: P1 basis.
        u: (3, n_p2) velocity dofs per component (m/s).  p: (n_p1,) pressure (Pa).
        fluxes_m3_per_s: cap name -> outward flow rate (m^3/s; the inlet's is negative).
        caps: cap name -> (centre, unit outward normal, radius).
        meta: solve statistics (JSON-able): sizes, Picard and GMRES iterations, times.
    """

    mesh: Any
    vbasis: Any
    pbasis: Any
    u: npt.NDArray[np.float64]
    p: npt.NDArray[np.float64]
    fluxes_m3_per_s: dict[str, float]
    caps: dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]]
    meta: dict[str, Any]
    _locator: Any = dataclasses.field(default=None, repr=False)


def _facet_index(mesh: Any, tris: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """skfem facet indices of the boundary triangles ``tris`` (k, 3)."""
    n = np.int64(mesh.p.shape[1])
    f = np.sort(mesh.facets, axis=0).astype(np.int64)
    key_f = (f[0] * n + f[1]) * n + f[2]
    t = np.sort(tris, axis=1).astype(np.int64)
    key_t = (t[:, 0] * n + t[:, 1]) * n + t[:, 2]
    order = np.argsort(key_f)
    pos = np.searchsorted(key_f[order], key_t)
    pos = np.clip(pos, 0, len(order) - 1)
    found = key_f[order][pos] == key_t
    if not found.all():
        raise RunError(f"{int((~found).sum())} boundary triangles are not facets of the tetrahedra")
    return np.asarray(order[pos], dtype=np.int64)


def _profile(X: npt.NDArray[np.float64], cap: tuple[Any, Any, float]) -> npt.NDArray[np.float64]:
    """Poiseuille shape 1 - (rho/R)^2 (clipped at 0) at points X (3, k) of a cap."""
    centre, n, r = cap
    d = X - centre[:, None]
    along = n @ d
    rho2 = np.einsum("ij,ij->j", d, d) - along ** 2
    return np.clip(1.0 - rho2 / (r * r), 0.0, None)


def solve_tree(tree: Tree3D, settings: Flow3DSettings, blood: BloodParams, meshed: Meshed3D | None = None,
               *, verbose: bool = False, progress: ProgressFn | None = None) -> FlowSolution3D:
    """Solve the steady Navier-Stokes flow through ``tree`` (see the module docstring).

    ``progress(done, total)`` is called after the mesh, assembly and multigrid set-up, after each Picard
    iteration and at the end (``done == total``: ``total`` counts the most iterations, so a converged solve
    jumps to it).

    Raises:
        ConfigError: gmsh cannot mesh the tree.
        RunError: the Picard iterations or a linear solve did not converge.
    """
    # deferred: scikit-fem, scipy.sparse and pyamg are heavy imports, paid only when a tree is solved
    import pyamg
    import scipy.sparse as sp
    from scipy.sparse.linalg import LinearOperator
    from skfem import Basis, BilinearForm, ElementTetP0, ElementTetP1, ElementTetP2, FacetBasis, Functional, MeshTet, asm

    t_start = time.perf_counter()
    report = progress or (lambda done, total: None)
    steps = settings.picard_max_iterations + 2  # mesh, assembly and AMG; the iterations; the fluxes
    report(0, steps)
    meshed = meshed or mesh_tree(tree, settings)
    log = print if verbose else (lambda *a, **k: None)
    m = MeshTet(np.ascontiguousarray(meshed.points.T), np.ascontiguousarray(meshed.tets.T))
    vb = Basis(m, ElementTetP2(), intorder=4)
    pb = vb.with_element(ElementTetP1())
    b0 = vb.with_element(ElementTetP0())
    facets = {k: _facet_index(m, v) for k, v in meshed.boundaries.items()}
    # viscosity per element: Pries at the local branch diameter
    cent = m.p[:, m.t].mean(axis=1).T
    d_el = np.round(local_diameter(tree, cent), 12)
    d_unique, inv = np.unique(d_el, return_inverse=True)
    mu_el = np.array([viscosity_for(blood, float(d)) for d in d_unique])[inv.ravel()]
    mu = b0.interpolate(mu_el)
    rho = blood.density_kg_per_m3

    @BilinearForm
    def viscous(u, v, w):  # type: ignore[no-untyped-def]  # skfem form: argument types are skfem's
        return w.mu * (u.grad[0] * v.grad[0] + u.grad[1] * v.grad[1] + u.grad[2] * v.grad[2])

    @BilinearForm
    def convection(u, v, w):  # type: ignore[no-untyped-def]  # skfem form: argument types are skfem's
        return rho * (w.w0 * u.grad[0] + w.w1 * u.grad[1] + w.w2 * u.grad[2]) * v

    @BilinearForm
    def pmass(p, q, w):  # type: ignore[no-untyped-def]  # skfem form: argument types are skfem's
        return p * q / w.mu

    def div_form(i: int) -> Any:
        return BilinearForm(lambda u, q, w: u.grad[i] * q)

    t_asm = time.perf_counter()
    A_visc = asm(viscous, vb, mu=mu).tocsr()
    Bs = [asm(div_form(i), vb, pb).tocsr() for i in range(3)]
    Mp = asm(pmass, pb, mu=pb.with_element(ElementTetP0()).interpolate(mu_el)).tocsr()
    ns, npr = A_visc.shape[0], Mp.shape[0]
    log(f"  mesh: {m.p.shape[1]} vertices, {m.t.shape[1]} tetrahedra; dofs: 3 x {ns} velocity + {npr} pressure "
        f"= {3 * ns + npr}; assembly {time.perf_counter() - t_asm:.1f} s")
    # Dirichlet data (the same dofs for the three components)
    X = vb.doflocs
    wall = vb.get_dofs(facets["wall"]).all()
    uD = np.zeros((3, ns))
    fixed = [wall]
    vc_in = settings.inlet_centreline_velocity_m_per_s

    def cap_values(name: str) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        dofs = np.setdiff1d(vb.get_dofs(facets[name]).all(), wall)
        return dofs, _profile(X[:, dofs], meshed.caps[name])

    def discrete_flux(name: str, dofs: npt.NDArray[np.int64], vals: npt.NDArray[np.float64]) -> float:
        """Flux of the P2 field with ``vals`` along the cap's normal at ``dofs`` (0 elsewhere) through the cap."""
        fb = FacetBasis(m, vb.elem, facets=facets[name], intorder=4)
        g = np.zeros(ns)
        g[dofs] = vals
        return float(asm(Functional(lambda w: w.g), fb, g=fb.interpolate(g)))

    d_in, prof_in = cap_values("inlet")
    n_in = meshed.caps["inlet"][1]
    for c in range(3):
        uD[c, d_in] = -vc_in * prof_in * n_in[c]
    fixed.append(d_in)
    q_in = discrete_flux("inlet", d_in, vc_in * prof_in)  # discrete inflow (m^3/s, > 0)
    outlets = [k for k in meshed.caps if k.startswith("outlet:")]
    radii = {k: meshed.caps[k][2] for k in outlets}
    free = list(outlets)
    if settings.outlets != "natural":
        power = 3.0 if settings.outlets == "murray" else 2.0
        total = sum(r ** power for r in radii.values())
        widest = max(outlets, key=lambda k: (radii[k], outlets.index(k)))
        free = [widest]
        for k in outlets:
            if k == widest:
                continue
            dk, prof = cap_values(k)
            scale = (radii[k] ** power / total) * q_in / discrete_flux(k, dk, prof)
            n_k = meshed.caps[k][1]
            for c in range(3):
                uD[c, dk] = scale * prof * n_k[c]
            fixed.append(dk)
    D = np.unique(np.concatenate(fixed))
    interior = np.setdiff1d(np.arange(ns), D)
    ni = len(interior)
    # condensed blocks
    Avis_II = A_visc[interior][:, interior].tocsr()
    BI = sp.hstack([B[:, interior] for B in Bs]).tocsr()
    BD = [B[:, D] for B in Bs]
    g_rhs = sum(BD[c] @ uD[c, D] for c in range(3))
    t_amg = time.perf_counter()
    ml = pyamg.smoothed_aggregation_solver(Avis_II, symmetry="hermitian", max_coarse=500)
    log(f"  AMG on the viscous block: {len(ml.levels)} levels, {time.perf_counter() - t_amg:.1f} s")
    minv = 1.0 / Mp.diagonal()
    vcycle = ml.aspreconditioner(cycle="V")

    def make_prec(n_u: int) -> LinearOperator:
        def apply(r: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
            r = np.asarray(r).ravel()
            p = -minv * r[n_u:]
            ru = r[:n_u] + BI.T @ p
            out = np.empty_like(r)
            for c in range(3):
                out[c * ni:(c + 1) * ni] = vcycle @ ru[c * ni:(c + 1) * ni]
            out[n_u:] = p
            return out
        return LinearOperator((n_u + npr, n_u + npr), matvec=apply, dtype=np.float64)

    prec = make_prec(3 * ni)
    report(1, steps)
    u = uD.copy()
    x = np.zeros(3 * ni + npr)
    change = math.inf
    gmres_its: list[int] = []
    it = 0
    for it in range(1, settings.picard_max_iterations + 1):
        if it == 1:
            A = A_visc
        else:
            wv = [vb.interpolate(u[c]) for c in range(3)]
            A = (A_visc + asm(convection, vb, w0=wv[0], w1=wv[1], w2=wv[2])).tocsr()
        A_II = A[interior][:, interior].tocsr()
        A_ID = A[interior][:, D]
        K = sp.bmat([[sp.block_diag([A_II] * 3), -BI.T], [-BI, None]], format="csr")
        rhs = np.concatenate([-(A_ID @ uD[c, D]) for c in range(3)] + [g_rhs])
        res: list[float] = []
        x, _info = pyamg.krylov.fgmres(K, rhs, x0=x, tol=settings.linear_tol, restart=100,
                                      maxiter=max(1, settings.linear_max_iterations // 100), M=prec, residuals=res)
        rel = float(np.linalg.norm(rhs - K @ x)) / max(float(np.linalg.norm(rhs)), 1e-300)
        gmres_its.append(len(res) - 1)
        if not (rel <= 10 * settings.linear_tol):
            raise RunError(f"3-D tree {tree.name!r}: the Oseen solve of Picard iteration {it} did not converge "
                           f"(relative residual {rel:.3g} after {len(res) - 1} GMRES iterations)")
        u_new = uD.copy()
        for c in range(3):
            u_new[c, interior] = x[c * ni:(c + 1) * ni]
        change = float(np.max(np.abs(u_new - u)) / max(float(np.max(np.abs(u_new))), 1e-300))
        u = u_new
        log(f"  Picard {it}: {len(res) - 1} GMRES iterations, residual {rel:.2e}, change {change:.2e} "
            f"({time.perf_counter() - t_start:.1f} s)")
        report(1 + it, steps)
        if it > 1 and change < settings.picard_tol:
            break
    else:
        raise RunError(f"3-D tree {tree.name!r}: Picard did not converge in {settings.picard_max_iterations} "
                       f"iterations (relative change {change:.3g} > {settings.picard_tol:g})")
    p = x[3 * ni:].copy()
    fluxes = {}
    for name in ["inlet", *outlets]:
        fb = FacetBasis(m, vb.elem, facets=facets[name], intorder=4)
        fluxes[name] = float(asm(Functional(lambda w: w.u0 * w.n[0] + w.u1 * w.n[1] + w.u2 * w.n[2]), fb,
                                 u0=fb.interpolate(u[0]), u1=fb.interpolate(u[1]), u2=fb.interpolate(u[2])))
    meta = {"tree": tree.name, "n_vertices": int(m.p.shape[1]), "n_tets": int(m.t.shape[1]),
            "n_dofs": int(3 * ns + npr), "mesh_size_m": settings.mesh_size_m,
            "inlet_centreline_velocity_m_per_s": vc_in,
            "wall_elements_per_circle": settings.wall_elements_per_circle, "outlets": settings.outlets,
            "free_outlets": free, "picard_iterations": it, "picard_change": change, "gmres_iterations": gmres_its,
            "discrete_inlet_flux_m3_per_s": q_in, "mesh_s": meshed.elapsed_s,
            "solve_s": time.perf_counter() - t_start}
    report(steps, steps)
    return FlowSolution3D(m, vb, pb, u, p, fluxes, dict(meshed.caps), meta)


class _Locator:
    """Point location in a tetrahedral mesh: k nearest centroids (KD tree), then barycentric coordinates."""

    def __init__(self, mesh: Any, vbasis: Any) -> None:
        from scipy.spatial import cKDTree  # deferred: scipy.spatial is heavy, needed only to evaluate a solution

        self.p = mesh.p.T.copy()
        self.t = mesh.t.T.copy()
        P = self.p[self.t]  # (t, 4, 3)
        cent = P.mean(axis=1)
        self.tree = cKDTree(cent)
        # a point farther than this from every centroid is in no element
        self.reach = float(np.max(np.linalg.norm(P - cent[:, None, :], axis=2)))
        T = np.transpose(P[:, 1:] - P[:, :1], (0, 2, 1))  # (t, 3, 3) columns b-a, c-a, d-a
        self.Tinv = np.linalg.inv(T)
        self.a = P[:, 0]
        self.edofs = vbasis.element_dofs.T.copy()  # (t, 10)
        # which vertex pair each of the P2 element's edge dofs sits on (from the dof locations of element 0)
        loc = vbasis.doflocs[:, vbasis.element_dofs[:, 0]].T
        pairs = []
        for k in range(4, 10):
            for i in range(4):
                for j in range(i + 1, 4):
                    if np.allclose(loc[k], 0.5 * (P[0, i] + P[0, j]), rtol=0, atol=1e-12 * (1 + np.abs(P[0]).max())):
                        pairs.append((i, j))
        if len(pairs) != 6:
            raise RunError("cannot identify the P2 tetrahedron's edge dofs")
        self.pairs = pairs

    def locate(self, q: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        """(element (m,), -1 outside; barycentric coordinates (m, 4)) of points q (m, 3).

        The 16 elements of the nearest centroids first, then the 128 nearest for the points not found
        (a point beside a long thin tetrahedron).
        """
        dmin, _i = self.tree.query(q)
        near = np.flatnonzero(dmin <= self.reach)
        el = np.full(len(q), -1, dtype=np.int64)
        lam = np.zeros((len(q), 4))
        el[near], lam[near], _d = self._locate(q[near], 16)
        miss = near[el[near] < 0]
        if len(miss):
            el2, lam2, _d = self._locate(q[miss], 128, 5000)
            el[miss], lam[miss] = el2, lam2
        return el, lam

    def _locate(self, q: npt.NDArray[np.float64], k: int, chunk: int = 50000
                ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        el = np.full(len(q), -1, dtype=np.int64)
        lam = np.zeros((len(q), 4))
        dmin = np.zeros(len(q))
        k = min(k, len(self.t))
        for s in range(0, len(q), chunk):
            qq = q[s:s + chunk]
            dist, cand = self.tree.query(qq, k=k)
            cand = cand.reshape(len(qq), k)
            dmin[s:s + chunk] = dist.reshape(len(qq), k)[:, 0]
            rel = qq[:, None, :] - self.a[cand]
            l123 = np.einsum("nkij,nkj->nki", self.Tinv[cand], rel)
            l0 = 1.0 - l123.sum(axis=2)
            lmin = np.minimum(l0, l123.min(axis=2))
            best = np.argmax(lmin, axis=1)
            ok = lmin[np.arange(len(qq)), best] >= -1e-9
            rows = np.arange(len(qq))[ok]
            el[s:s + chunk][ok] = cand[rows, best[ok]]
            lam[s:s + chunk][ok, 0] = l0[rows, best[ok]]
            lam[s:s + chunk][ok, 1:] = l123[rows, best[ok]]
        return el, lam, dmin


def _locator(sol: FlowSolution3D) -> _Locator:
    if sol._locator is None:
        sol._locator = _Locator(sol.mesh, sol.vbasis)
    loc: _Locator = sol._locator
    return loc


def evaluate(sol: FlowSolution3D, points_m: npt.ArrayLike
             ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """(velocity (m, 3) m/s, pressure (m,) Pa, inside (m,)) at points (m, 3); zero outside the mesh."""
    q = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
    loc = _locator(sol)
    el, lam = loc.locate(q)
    ok = el >= 0
    vel = np.zeros((len(q), 3))
    pr = np.zeros(len(q))
    if ok.any():
        L = lam[ok]
        N = np.empty((len(L), 10))
        N[:, :4] = L * (2.0 * L - 1.0)
        for k, (i, j) in enumerate(loc.pairs):
            N[:, 4 + k] = 4.0 * L[:, i] * L[:, j]
        dofs = loc.edofs[el[ok]]
        for c in range(3):
            vel[ok, c] = np.einsum("nk,nk->n", N, sol.u[c][dofs])
        pr[ok] = np.einsum("nk,nk->n", L, sol.p[loc.t[el[ok]]])
    return vel, pr, ok


def sample_grid(sol: FlowSolution3D, spacing_m: float, margin_m: float
                ) -> tuple[npt.NDArray[np.float64], float, npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Velocity on a regular grid around the mesh, for a trilinear lookup.

    Args:
        sol: The solution.
        spacing_m: Grid spacing (m).
        margin_m: Margin around the mesh's bounding box (m).

    Returns:
        (origin (3,) m, spacing m, velocity (nx, ny, nz, 3) m/s (zero outside the lumen),
        inside (nx, ny, nz) bool: the node lies in the mesh).  Nodes lie on multiples of the spacing.
    """
    lo = sol.mesh.p.min(axis=1) - margin_m
    hi = sol.mesh.p.max(axis=1) + margin_m
    origin = np.floor(lo / spacing_m) * spacing_m
    n = (np.ceil((hi - origin) / spacing_m)).astype(int) + 1
    axes = [origin[k] + spacing_m * np.arange(n[k]) for k in range(3)]
    G = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    vel, _p, ok = evaluate(sol, G)
    return origin, float(spacing_m), vel.reshape(n[0], n[1], n[2], 3), ok.reshape(n[0], n[1], n[2])


def section_flux(sol: FlowSolution3D, centre_m: npt.ArrayLike, normal: npt.ArrayLike, radius_m: float,
                 n_radial: int = 24, n_angular: int = 64) -> tuple[float, float, float]:
    """(flux m^3/s along ``normal``, mean pressure Pa, area m^2 inside the mesh) through a disc cross-section.

    Gauss-Legendre in the radius, uniform in the angle, on the disc of ``radius_m`` about
    ``centre_m`` normal to ``normal``; points outside the mesh count zero velocity (the sliver between
    the polygonal mesh wall and the circle, where the velocity is O(h^2) anyway).
    """
    c = np.asarray(centre_m, dtype=np.float64)
    n = _unit(np.asarray(normal, dtype=np.float64))
    e1 = _any_normal(n)
    e2 = np.cross(n, e1)
    xg, wg = np.polynomial.legendre.leggauss(n_radial)
    r = 0.5 * radius_m * (xg + 1.0)
    wr = 0.5 * radius_m * wg * r
    th = 2.0 * np.pi * np.arange(n_angular) / n_angular
    R, TH = np.meshgrid(r, th, indexing="ij")
    W = (wr[:, None] * np.full(n_angular, 2.0 * np.pi / n_angular)[None, :]).ravel()
    pts = c + (R.ravel() * np.cos(TH.ravel()))[:, None] * e1 + (R.ravel() * np.sin(TH.ravel()))[:, None] * e2
    vel, pr, ok = evaluate(sol, pts)
    area = float(np.sum(W[ok]))
    return float(np.sum(W * (vel @ n))), float(np.sum(W[ok] * pr[ok]) / max(area, 1e-300)), area


# ----------------------------------------------------------------------------------------------- cache


def cache_dir() -> Path:
    """Where 3-D solutions are cached: ``$VESSELBOT_CFD_CACHE/3d`` or ``~/.cache/vesselbot_ros/cfd/3d``."""
    from vesselbot_ros.vessels.cfd import cache_dir as cache_2d  # deferred: cfd imports the kernel; only the cache needs its folder

    return cache_2d() / "3d"


def solution_key(tree: Tree3D, settings: Flow3DSettings, blood: BloodParams) -> str:
    """Cache key: sha256 of the tree, the settings, the blood model and the cache version."""
    text = json.dumps({"tree": dataclasses.asdict(tree), "settings": dataclasses.asdict(settings),
                       "blood": to_mapping(blood), "v": CACHE_VERSION}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def _save(sol: FlowSolution3D, path: Path) -> None:
    """Write atomically (temporary file, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    caps = {k: [c.tolist(), n.tolist(), r] for k, (c, n, r) in sol.caps.items()}
    with atomic_open(path, "wb") as fh:
        np.savez_compressed(fh, points=sol.mesh.p, tets=sol.mesh.t.astype(np.int32), u=sol.u, p=sol.p,
                            info=np.array(json.dumps({"fluxes": sol.fluxes_m3_per_s, "caps": caps,
                                                      "meta": sol.meta})))


def _load(path: Path) -> FlowSolution3D:
    from skfem import Basis, ElementTetP1, ElementTetP2, MeshTet  # deferred: scikit-fem is heavy, only to rebuild a cached solution

    with np.load(path) as z:
        pts, tets, u, p = z["points"], z["tets"].astype(np.int64), z["u"], z["p"]
        info = json.loads(str(z["info"]))
    m = MeshTet(np.ascontiguousarray(pts), np.ascontiguousarray(tets))
    vb = Basis(m, ElementTetP2(), intorder=4)
    if u.shape != (3, vb.N):
        raise ValueError("cached velocity does not fit its mesh")
    caps = {k: (np.array(c), np.array(n), float(r)) for k, (c, n, r) in info["caps"].items()}
    return FlowSolution3D(m, vb, vb.with_element(ElementTetP1()), u, p, info["fluxes"], caps, info["meta"])


def solve_tree_cached(tree: Tree3D, settings: Flow3DSettings, blood: BloodParams, *, refresh: bool = False,
                      verbose: bool = False, progress: ProgressFn | None = None) -> tuple[FlowSolution3D, Path]:
    """The solution of ``tree``: read from the cache, or solved and cached (never on failure).

    ``progress``: :func:`solve_tree`'s, called only if the tree is solved.

    Returns:
        (solution, its cache file).
    """
    path = cache_dir() / f"{tree.name}-{solution_key(tree, settings, blood)}.npz"
    if not refresh and path.is_file():
        try:
            sol = _load(path)
            sol.meta["cached"] = True
            return sol, path
        except (OSError, ValueError, KeyError):
            pass  # a torn or foreign file: solve again
    sol = solve_tree(tree, settings, blood, verbose=verbose, progress=progress)
    _save(sol, path)
    return sol, path
