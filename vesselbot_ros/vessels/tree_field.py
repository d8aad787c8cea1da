"""What the plant reads of a vessel tree in space: the meshed wall and the steady 3-D flow, on one regular grid.

A 3-D network (:attr:`~vesselbot_ros.vessels.network.VesselNetworkParams.is_3d`: its file gives ``y_m``) is
solved once by :mod:`vesselbot_ros.vessels.tree_cfd` (steady Navier-Stokes, Pries viscosity, the network's
``cfd.outlet_split`` imposed at the outlets) and sampled for the plant:

* the wall: the surface of the same fused solid the flow is solved in, meshed alone
  (:func:`~vesselbot_ros.vessels.tree_mesh.mesh_wall`: facets sagging about ``WALL_SAG_M`` = 0.5 um off the CAD
  surface, where the flow mesh's 0.3-0.8 mm facets sag up to 7.5-20 um; its caps, flat faces of the solid,
  left out), whose exact signed distance, smooth inward normal and local (ball) diameter
  :mod:`vesselbot_ros.geometry.surface_query` answers, sampled on the grid by
  :mod:`vesselbot_ros.geometry.field_build`;
* the flow: the P2 velocity at the grid's nodes, normalised to an inlet centreline velocity of 1 (the plant
  scales it by ``physics.flow.centreline_velocity_m_per_s`` and the pulse (12), as the planar network's),
  zero outside the mesh; the blood viscosity at each node is Pries' at the node's local diameter.

The flow mesh's own wall (10-23 thousand triangles) is kept for views to draw (:func:`wall_mesh`); the plant's
has 0.2-0.45 million.

Grid: spacing ``cfd.grid_spacing_3d_m`` (0: 0.1 mm), nodes on multiples of it, round the wall with a margin
of 0.3 mm plus two spacings.

Standard of the sampled wall: within ``BAND_M`` (1 mm) of the wall in the lumen and ``OUT_BAND_M`` (0.1 mm)
outside it, distance within 5 um and normal within 2 deg of the exact query (the cells interpolation cannot
answer go to it -- over the few triangles nearest the point's 25 or 12.5 um part of the cell, ``LIST_MAX`` -- a vessel's axis or a
junction's medial cell to the least of a few tubes, ridges or planes fitted to the cell), but for the normal within micrometres of a
medial surface (a vessel's axis, a junction's bisector), where the exact normal itself jumps
(tools/validate_wall_field3d.py ``--shipped``: 15 / 0 / 15 points in 2 x 10^5 off by more than 2 deg there).
Outside the lumen by more, where a bead's centre never is (a run counts that time as outside the lumen), and
deeper in it, the lookup interpolates whatever the error
(the sign is kept): the wall's net force there -- the near and the far wall's electrostatic pull, the other
terms being nil across such gaps; the drag's wall factor reads the diameter -- is at most 2-4.5 % of the
bead's weight at 1 mm (D = 2.4-8 mm, the shipped physics) and vanishes towards the medial surface, where the
normal is undefined; the flow's dilation shift along the normal vanishes there too (D / 2 = s).

Shipped, cached, or solved.  The samples (the plant's wall, the view's wall, caps, grid, flow) of a tree and
blood model are one file, ``<network>-<key>.3d.npz`` (3.5-6 MB; the plant's wall written compactly:
:meth:`TreeField.save`): shipped with the scenarios' networks in ``config/cfd/``, else cached in
:func:`~vesselbot_ros.vessels.tree_cfd.cache_dir`, else solved (minutes) and cached.  The wall field built from
them is cached beside them (a ``.wall`` folder, not shipped, mapped by every process that reads it); measured (a
2-core machine, otherwise quiet): III-C 50 s, 134 MB;
carotid 38 s, 128 MB; synthetic tree 165 s, 480 MB (its 7.6 million-node grid round a sparse tree is 244 MB of
it; most of the time goes to the list cells' sub-cube lists, which make its lookup 1.9x the planar one's
instead of 4.1x) -- against 26 s, 127 MB; 105 s, 1.55 GB; 95 s, 1.05 GB with the flow mesh's wall and the whole candidate
tree.  A torn, foreign or older file is solved or built again; a failed solve caches nothing.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.atomic_io import atomic_open
from vesselbot_ros.config import ConfigError, to_mapping
from vesselbot_ros.geometry.field_build import WallField3D, build_wall_field3d, grid_box
from vesselbot_ros.geometry.field_lookup import field_points3d, wall_field3d
from vesselbot_ros.geometry.surface_wall import Wall3D
from vesselbot_ros.physics.blood_viscosity import blood_viscosity
from vesselbot_ros.physics.kernel import pack_params
from vesselbot_ros.physics.params import BloodParams, PhysicsParams, planar_twin
from vesselbot_ros.progress import ProgressFn, step
from vesselbot_ros.resources import fmt_bytes, fmt_seconds, require_fits
from vesselbot_ros.vessels import tree_cfd, tree_mesh
from vesselbot_ros.vessels.cfd import network_wall, packed_params
from vesselbot_ros.vessels.network import VesselNetworkParams, load_network, smooth_centreline, with_flow_preset

__all__ = ["packed_vessel", "vessel_geom", "TreeField", "TreeBuildEstimate", "build_estimate", "check_build",
           "flow_settings", "grid_spacing_m", "field_key", "plant_field", "wall_mesh", "FIELD3D_VERSION",
           "WallArrays", "meshed_wall",
           "PackedTree", "packed_tree", "planar_twin", "wall_arrays", "wall_cache_path", "WALL_NAMES"]

#: Bumped when the file's content or its meaning changes (a new key: old files are ignored).
FIELD3D_VERSION = 2
#: Bumped when the wall field built from the samples changes (a cached ``.wall`` of another is built again).
#: 9: the ball diameter at a convex crease (the ball through the exact nearest wall point counts); 8: model cells' axes
#: by a BLAS-free eigen-solver (one sign; a cache built under AVX-512 differed).
WALL_VERSION = 9
#: The grid's margin round the wall (m), plus two spacings.
GRID_MARGIN_M = 3.0e-4
#: Default spacing of the plant's grid (m).
DEFAULT_SPACING_M = 1.0e-4
#: The plant's wall: the facets' sag off the CAD surface (m) (:func:`~vesselbot_ros.vessels.tree_mesh.mesh_wall`).
WALL_SAG_M = 0.5e-6
#: The wall field's standard holds within this of the wall in the lumen (m) ...
BAND_M = 1.0e-3
#: ... and within this outside it (m): a bead's centre is in the lumen (module docstring).
OUT_BAND_M = 1.0e-4
#: Sub-cells per axis of a flagged cell that reaches into the lumen.
REFINE = 2
#: The wall's candidate tree is finest (0.2 mm) within this of the wall (m) ...
NEAR_M = 0.6e-3
#: ... and the lookup's, kept where it asks the exact query, down to 0.1 mm (depth 5 under 3.2 mm roots).
EXACT_DEPTH = 5
#: The longest triangle list of a list cell (:func:`~vesselbot_ros.geometry.field_build.build_wall_field3d`).
LIST_MAX = 256
#: Vertices are stored in the samples' file on this lattice (m).
_QUANTUM_M = 1.0e-9

# What a tree's samples and wall field cost, estimated before they are built (:func:`build_estimate`).
#: gmsh's tetrahedra per (lumen volume / edge^3), the edge the lumen's or the wall's (2 pi r / elements per
#: circle), whichever is smaller: fitted to the shipped trees' flow meshes (5.3-5.8).
TETS_PER_EDGE_VOLUME = 6.0
#: The 3-D flow solve's memory and time per tetrahedron (P2/P1 assembly, AMG, FGMRES): measured 23-28 KB and
#: 2.3 ms on a tube of 5-12 thousand, the shipped trees solved in 0.9-2.9 ms each (a 2-core machine, loaded).
TET_BYTES = 32.0 * 1024
TET_SECONDS = 3.0e-3
#: The plant's wall: triangles per (wall area / size^2), the size :func:`~vesselbot_ros.vessels.tree_mesh.mesh_wall`'s
#: ``sqrt(6 r sag)`` (fitted to the shipped walls: 2.2-2.6); memory (gmsh, the exact wall's tree) and time each.
TRIANGLES_PER_SIZE_AREA = 2.7
WALL_TRIANGLE_BYTES = 1024.0
WALL_TRIANGLE_SECONDS = 1.0e-4
#: Per node of the plant's grid: the sampling's float64 copies and the wall field's build (the synthetic tree:
#: 7.6 million nodes, 480 MB and 165 s for the wall field), bytes and s.
NODE_BYTES = 192.0
NODE_SECONDS = 5.0e-5

Array = npt.NDArray[np.float64]


def flow_settings(net: VesselNetworkParams) -> tree_cfd.Flow3DSettings:
    """The 3-D solve of ``net`` as its ``cfd`` block sets it (module docstring)."""
    c = net.cfd
    return tree_cfd.Flow3DSettings(
        inlet_centreline_velocity_m_per_s=c.inlet_centreline_velocity_m_per_s,
        mesh_size_m=c.mesh_size_3d_m if c.mesh_size_3d_m > 0.0 else 1.2 * c.mesh_size_m,
        wall_elements_per_circle=c.wall_elements_per_circle_3d or 32,
        outlets=c.outlet_split,
        picard_max_iterations=c.picard_max_iterations,
        outlet_shares=tuple(zip(c.share_outlets, c.outlet_shares)))


def grid_spacing_m(net: VesselNetworkParams) -> float:
    """Spacing (m) of the plant's grid of ``net``."""
    return net.cfd.grid_spacing_3d_m if net.cfd.grid_spacing_3d_m > 0.0 else DEFAULT_SPACING_M


def field_key(net: VesselNetworkParams, blood: BloodParams) -> str:
    """The samples' key: sha256 of the tree, its solve settings, the grid, the blood model and the version."""
    tree = tree_mesh.tree_from_network(net)
    text = json.dumps({"tree": dataclasses.asdict(tree), "settings": tree_cfd.settings_mapping(flow_settings(net)),
                       "h": grid_spacing_m(net), "sag": WALL_SAG_M, "blood": to_mapping(blood), "v": FIELD3D_VERSION},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


@dataclasses.dataclass
class WallArrays:
    """The compiled wall lookup's arrays (:func:`~vesselbot_ros.geometry.field_lookup.wall_field3d`'s ``args``),
    queried as the planar network's wall is (:class:`~vesselbot_ros.geometry.polyline_wall.WallQuery`)."""

    args: tuple[npt.NDArray[Any], ...]
    stats: dict[str, float]

    def query(self, points_m: npt.ArrayLike) -> dict[str, npt.NDArray[np.float64]]:
        """``sdist`` (m,) m (> 0 inside), ``normal`` (m, 3) unit inward normal, ``diameter`` (m,) m at points (m, 3),
        as the plant reads them."""
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(points_m, dtype=np.float64)))
        r = field_points3d(q, *self.args)
        return {"sdist": r[:, 0], "normal": r[:, 1:4], "diameter": r[:, 4]}

    def clearance(self, x_m: float, y_m: float, z_m: float) -> tuple[float, float]:
        """(signed distance (m, > 0 inside), local diameter (m)) at one point, compiled (a few microseconds)."""
        r = wall_field3d(float(x_m), float(y_m), float(z_m), *self.args)
        return float(r[0]), float(r[4])


def meshed_wall(net: VesselNetworkParams, blood: BloodParams | None = None) -> Any:
    """The plant's meshed wall of ``net`` on its own axes, one query for both: ``query(points)`` (``sdist``,
    ``normal``, ``diameter``) and ``clearance(*point)`` (the signed distance and the diameter at one point).

    The axis count's branch at the vessels' edge: a planar network's wall
    (:func:`~vesselbot_ros.vessels.cfd.network_wall`, points (x, z)) or a 3-D tree's lookup (:func:`wall_arrays`,
    points (x, y, z); built and cached on first use).
    """
    return wall_arrays(net, blood) if net.is_3d else network_wall(net, blood)


@dataclasses.dataclass
class TreeField:
    """The samples of one tree (module docstring).

    Attributes:
        name: The network's name.  key: :func:`field_key`.
        vertices: (n, 3) the plant's wall vertices (m), on a 1 nm lattice.  triangles: (k, 3) its triangles (caps
            excluded): the solid's surface meshed alone (:func:`~vesselbot_ros.vessels.tree_mesh.mesh_wall`).
        caps: cap name -> (centre (3,), unit outward normal (3,), radius m).
        origin: (3,) grid origin (m).  h: spacing (m).  shape: (nx, ny, nz) nodes.
        velocity: (nz, ny, nx, 3) float32 velocity per unit inlet centreline velocity (-).
        meta: the solve's and the wall mesh's figures.
        view_vertices, view_triangles: The flow mesh's wall (caps excluded; coarser, within its facets' sag of
            the same solid): what a view draws.
    """

    name: str
    key: str
    vertices: Array
    triangles: npt.NDArray[np.int64]
    caps: dict[str, tuple[Array, Array, float]]
    origin: Array
    h: float
    shape: tuple[int, int, int]
    velocity: npt.NDArray[np.float32]
    meta: dict[str, Any]
    view_vertices: Array
    view_triangles: npt.NDArray[np.int64]

    def save(self, path: Path) -> None:
        """Write atomically (temporary file, then rename).

        The plant's wall (in :func:`_canonical_wall`'s order) is written compactly, being most of the file:
        vertices as integer nanometres from the grid's origin differenced along the rows, triangles as their
        first vertex differenced along the rows and the other two less the first (small numbers, which
        deflate well); :meth:`load` restores them exactly.
        """
        caps = {k: [c.tolist(), n.tolist(), r] for k, (c, n, r) in self.caps.items()}
        info = {"name": self.name, "key": self.key, "h": self.h, "shape": list(self.shape), "caps": caps,
                "meta": self.meta, "v": FIELD3D_VERSION}
        q = np.rint((self.vertices - self.origin) / _QUANTUM_M).astype(np.int64)
        t = self.triangles
        _atomic_savez(path, True, wall_q=np.diff(q, axis=0, prepend=0).astype(np.int32),
                      wall_t=np.column_stack([np.diff(t[:, 0], prepend=0), t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]]).astype(np.int32),
                      vertices=self.view_vertices, triangles=self.view_triangles.astype(np.int32),
                      origin=self.origin, velocity=self.velocity, info=np.array(json.dumps(info)))

    @classmethod
    def load(cls, path: Path) -> TreeField:
        """Read a file :meth:`save` wrote (ValueError / KeyError / OSError if it is not one)."""
        with np.load(path) as z:
            info = json.loads(str(z["info"]))
            if info.get("v") != FIELD3D_VERSION:
                raise ValueError(f"{path}: version {info.get('v')!r}, not {FIELD3D_VERSION}")
            shape = tuple(int(v) for v in info["shape"])
            vel = np.ascontiguousarray(z["velocity"], dtype=np.float32)
            if vel.shape != (shape[2], shape[1], shape[0], 3):
                raise ValueError(f"{path}: velocity {vel.shape} does not fit the grid {shape}")
            caps = {k: (np.array(c, dtype=np.float64), np.array(n, dtype=np.float64), float(r))
                    for k, (c, n, r) in info["caps"].items()}
            origin = np.asarray(z["origin"], dtype=np.float64)
            verts = origin + _QUANTUM_M * np.cumsum(z["wall_q"].astype(np.int64), axis=0).astype(np.float64)
            wt = z["wall_t"].astype(np.int64)
            first = np.cumsum(wt[:, 0])
            tri = np.column_stack([first, first + wt[:, 1], first + wt[:, 2]])
            return cls(info["name"], info["key"], np.ascontiguousarray(verts), np.ascontiguousarray(tri), caps, origin,
                       float(info["h"]), (shape[0], shape[1], shape[2]), vel, info["meta"],
                       np.asarray(z["vertices"], dtype=np.float64), np.asarray(z["triangles"], dtype=np.int64))

    @functools.cached_property
    def wall(self) -> Wall3D:
        """The exact wall, its candidate tree covering the grid (what the build asks): leaves of 0.2 mm within
        ``NEAR_M`` of the wall (most of the build's queries), of 0.4 to 0.8 mm deeper in the lumen, sealed (no
        list) wholly outside it beyond the outer band and 3 h."""
        return self.block_wall(None)

    def block_wall(self, box_m: tuple[Array, Array] | None) -> Wall3D:
        """:attr:`wall` with its candidate tree's roots over ``box_m`` (lo, hi) only (m; None: all of them), for a
        build whose queries stay in the box (:mod:`vesselbot_ros.analysis.builds_fingerprint`)."""
        return plant_wall3d(self.vertices, self.triangles, list(self.caps.values()), self.h, box_m)

    def viscosity(self, blood: BloodParams, diameter_m: Array) -> Array:
        """Pries' viscosity (Pa s) of ``blood`` at local diameters (m)."""
        d = np.asarray(diameter_m, dtype=np.float64)
        uniq, inv = np.unique(np.round(d, 7), return_inverse=True)
        # eq. (9) over the distinct diameters at once (thousands: a Python call each took seconds per tree)
        eta = blood_viscosity(np.maximum(uniq, 1e-6), blood.hematocrit, blood.plasma_viscosity_Pa_s,
                              blood.viscosity_model, blood.constant_viscosity_Pa_s)
        return np.asarray(eta[inv].reshape(d.shape), dtype=np.float64)


def _atomic_savez(path: Path, compressed: bool, **arrays: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "wb") as fh:
        (np.savez_compressed if compressed else np.savez)(fh, **arrays)


def shipped_dir() -> Path:
    """Where the shipped networks' samples live (the 2-D fields' folder, ``config/cfd``)."""
    from vesselbot_ros.vessels.cfd import shipped_field_dir  # deferred: cfd imports the planar kernel; only its folder is needed

    return shipped_field_dir()


def _canonical_wall(vertices: Array, triangles: npt.NDArray[np.int64], origin: Array
                    ) -> tuple[Array, npt.NDArray[np.int64]]:
    """The wall in the order its file keeps: vertices on the 1 nm lattice from ``origin``, sorted along a Morton
    curve of 20 um cells; each triangle rotated (orientation kept) to start at its least vertex, the triangles
    sorted.  Near vertices get near numbers, so the file's differences are small."""
    q = np.rint((vertices - origin) / _QUANTUM_M).astype(np.int64)
    cell = ((q - q.min(axis=0)) // 20_000).astype(np.uint64)
    code = np.zeros(len(q), dtype=np.uint64)
    for bit in range(21):
        for ax in range(3):
            code |= ((cell[:, ax] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + ax)
    order = np.argsort(code, kind="stable")
    new = np.empty_like(order)
    new[order] = np.arange(len(order))
    t = new[triangles]
    roll = np.argmin(t, axis=1)
    t = np.take_along_axis(t, (roll[:, None] + np.arange(3)[None, :]) % 3, axis=1)
    t = t[np.lexsort((t[:, 2], t[:, 1], t[:, 0]))]
    return origin + _QUANTUM_M * q[order].astype(np.float64), np.ascontiguousarray(t.astype(np.int64))


def _wall_triangles(sol: tree_cfd.FlowSolution3D) -> npt.NDArray[np.int64]:
    """The mesh's boundary triangles that are not on a cap (a cap: in its plane, within 1.05 of its radius)."""
    m = sol.mesh
    tri = np.asarray(m.facets[:, m.boundary_facets()].T, dtype=np.int64)
    cen = m.p.T[tri].mean(axis=1)
    on_cap = np.zeros(len(tri), dtype=bool)
    for c, n, r in sol.caps.values():
        d = cen - c
        along = d @ n
        rad = np.sqrt(np.maximum(np.einsum("ij,ij->i", d, d) - along ** 2, 0.0))
        on_cap |= (np.abs(along) < 1e-3 * r) & (rad < 1.05 * r)
    return tri[~on_cap]


def _sample(net: VesselNetworkParams, blood: BloodParams, key: str, progress: ProgressFn | None = None) -> TreeField:
    """Solve (or read the cached solve), mesh the wall and sample (module docstring).

    ``progress(done, total)``: the solve's steps (none if it is cached), then the wall's mesh and the sampling.
    """
    t0 = time.perf_counter()
    settings = flow_settings(net)
    tree = tree_mesh.tree_from_network(net)
    report = progress or (lambda done, total: None)
    steps = [3]  # a cached solve, the wall's mesh, the sampling; a solve's own steps replace the first

    def solving(done: int, total: int) -> None:
        steps[0] = total + 2
        report(done, steps[0])

    sol, _path = tree_cfd.solve_tree_cached(tree, settings, blood, progress=solving)
    report(steps[0] - 2, steps[0])
    vtri = _wall_triangles(sol)
    used, inv = np.unique(vtri, return_inverse=True)
    view_verts = np.ascontiguousarray(sol.mesh.p.T[used])
    vtri = inv.reshape(-1, 3).astype(np.int64)
    wm = tree_mesh.mesh_wall(tree, WALL_SAG_M)
    report(steps[0] - 1, steps[0])
    h = grid_spacing_m(net)
    origin, shape = grid_box(wm.vertices.min(axis=0), wm.vertices.max(axis=0), h, GRID_MARGIN_M + 2.0 * h)
    verts, tri = _canonical_wall(wm.vertices, wm.triangles, origin)
    nx, ny, nz = shape
    g = np.stack(np.meshgrid(origin[0] + h * np.arange(nx), origin[1] + h * np.arange(ny),
                             origin[2] + h * np.arange(nz), indexing="ij"), axis=-1)  # (nx, ny, nz, 3)
    pts = g.transpose(2, 1, 0, 3).reshape(-1, 3)  # x fastest
    vel, _p, _ok = tree_cfd.evaluate(sol, pts)
    vel32: npt.NDArray[np.float32] = (vel / settings.inlet_centreline_velocity_m_per_s).reshape(nz, ny, nx, 3).astype(np.float32)
    meta = {"solve": sol.meta, "wall": wm.meta, "sample_s": time.perf_counter() - t0, "wall_triangles": int(len(tri)),
            "view_triangles": int(len(vtri)), "nodes": int(nx * ny * nz)}
    report(steps[0], steps[0])
    return TreeField(net.name, key, verts, tri, dict(wm.caps), origin, h, (nx, ny, nz), vel32, meta, view_verts, vtri)


@dataclasses.dataclass(frozen=True)
class TreeBuildEstimate:
    """What building a tree's samples and wall field would take (:func:`build_estimate`).

    Attributes:
        tets: Tetrahedra of the flow mesh.  triangles: Triangles of the plant's wall.  nodes: Nodes of the grid.
        solve_bytes, solve_s: The flow solve's peak memory (bytes) and time (s).
        sample_bytes, sample_s: The wall mesh's, the grid's sampling's and the wall field's.
    """

    tets: float
    triangles: float
    nodes: float
    solve_bytes: float
    solve_s: float
    sample_bytes: float
    sample_s: float


def build_estimate(net: VesselNetworkParams) -> TreeBuildEstimate:
    """Estimate, from the smoothed centrelines alone, what :func:`plant_field` and :func:`wall_arrays` would build."""
    st = flow_settings(net)
    h = grid_spacing_m(net)
    vol = tris = 0.0
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for b in net.branches:
        p, r, arc = smooth_centreline(b, net.smoothing, net.sample_spacing_m, 3)
        dl, rm = np.diff(arc), 0.5 * (r[1:] + r[:-1])
        edge = np.minimum(st.mesh_size_m, 2.0 * np.pi * rm / st.wall_elements_per_circle)
        vol += float((np.pi * rm ** 2 * dl / edge ** 3).sum())
        size2 = np.minimum(6.0 * rm * WALL_SAG_M, 1.0e-6)
        tris += float((2.0 * np.pi * rm * dl / size2).sum())
        lo = np.minimum(lo, (p - r[:, None]).min(axis=0))
        hi = np.maximum(hi, (p + r[:, None]).max(axis=0))
    tets = TETS_PER_EDGE_VOLUME * vol
    tris *= TRIANGLES_PER_SIZE_AREA
    nodes = float(np.prod((hi - lo + 2.0 * (GRID_MARGIN_M + 2.0 * h)) / h + 1.0))
    return TreeBuildEstimate(tets, tris, nodes, TET_BYTES * tets, TET_SECONDS * tets,
                           WALL_TRIANGLE_BYTES * tris + NODE_BYTES * nodes, WALL_TRIANGLE_SECONDS * tris + NODE_SECONDS * nodes)


def check_build(net: VesselNetworkParams, blood: BloodParams | None = None, *, quiet: bool = False) -> TreeBuildEstimate | None:
    """Refuse, before anything is meshed, a tree whose samples or wall field would not fit (memory, time).

    Nothing is estimated when the samples and the wall field are shipped or cached.  Otherwise one line on
    stderr says what will be built (``meshing <tree> (about N cells, est. M MiB)``) unless ``quiet``.

    Returns:
        The estimate, or None if nothing is to be built.

    Raises:
        ConfigError: one line naming ``cfd.mesh_size_3d_m`` (the flow solve) or ``cfd.grid_spacing_3d_m`` (the
            grid and the wall), its value and the estimate.
    """
    blood = blood if blood is not None else BloodParams()
    key = field_key(net, blood)
    have_samples = any((d / f"{net.name}-{key}.3d.npz").is_file() for d in (shipped_dir(), tree_cfd.cache_dir()))
    if have_samples and (wall_cache_path(net.name, key) / "stats.json").is_file():
        return None
    est = build_estimate(net)
    c = net.cfd
    if not have_samples:
        mesh = repr(c.mesh_size_3d_m) if c.mesh_size_3d_m > 0.0 else f"0 (the default, {flow_settings(net).mesh_size_m:g} m)"
        require_fits("cfd.mesh_size_3d_m", mesh, est.solve_bytes, est.solve_s,
                     what=f"the 3-D flow solve of tree {net.name!r} ({est.tets:.3g} tetrahedra)",
                     hint="raise cfd.mesh_size_3d_m or lower cfd.wall_elements_per_circle_3d in the tree's cfd: block")
    spacing = repr(c.grid_spacing_3d_m) if c.grid_spacing_3d_m > 0.0 else f"0 (the default, {DEFAULT_SPACING_M:g} m)"
    require_fits("cfd.grid_spacing_3d_m", spacing, est.sample_bytes, est.sample_s,
                 what=f"the 3-D wall and grid of tree {net.name!r} ({est.nodes:.3g} grid nodes, "
                      f"{est.triangles:.3g} wall triangles)",
                 hint="raise cfd.grid_spacing_3d_m in the tree's cfd: block")
    if not quiet:
        peak = max(est.solve_bytes if not have_samples else 0.0, est.sample_bytes)
        secs = (est.solve_s if not have_samples else 0.0) + est.sample_s
        what = (f"meshing {net.name} (about {est.tets:.3g} cells, " if not have_samples else
                f"building the 3-D wall field of {net.name} (about ")
        print(f"{what}{est.nodes:.3g} grid nodes, est. {fmt_bytes(peak)}, up to {fmt_seconds(secs)}; built once, "
              "then cached)", file=sys.stderr, flush=True)
    return est


@functools.lru_cache(maxsize=8)
def plant_field(net: VesselNetworkParams, blood: BloodParams | None = None, *, refresh: bool = False) -> TreeField:
    """The samples of ``net`` for ``blood`` (default: the shipped scenarios' blood): shipped, cached, or solved.

    Raises:
        ConfigError: ``net`` is not written in 3-D (the planar plant takes it).
    """
    if not net.is_3d:
        raise ConfigError(f"vessel network {net.name!r} gives no y_m: the planar plant takes it, not the 3-D one")
    blood = blood if blood is not None else BloodParams()
    key = field_key(net, blood)
    name = f"{net.name}-{key}.3d.npz"
    cached = tree_cfd.cache_dir() / name
    for found in () if refresh else (shipped_dir() / name, cached):
        if found.is_file():
            try:
                return TreeField.load(found)
            except (OSError, ValueError, KeyError):
                pass  # a torn or foreign file: solve again
    check_build(net, blood)  # before anything is meshed: one line if it does not fit, else one saying what is built
    with step(f"3-D flow of {net.name}") as report:  # a bar when a command draws them (vesselbot_ros.progress)
        fld = _sample(net, blood, key, report)
    with contextlib.suppress(OSError):  # a full or read-only cache: the run goes on with the samples in memory
        fld.save(cached)
    return fld


def plant_wall3d(vertices: Array, triangles: npt.NDArray[np.int64], caps: list[Any], h_m: float,
                 box_m: tuple[Array, Array] | None = None) -> Wall3D:
    """The exact wall at the plant's settings for a field of spacing ``h_m``: its candidate tree covering the grid
    (what the build asks), leaves of 0.2 mm within ``NEAR_M`` of the wall, of 0.4 to 0.8 mm deeper in the lumen,
    sealed (no list) wholly outside it beyond the outer band and 3 h; roots over ``box_m`` only if given
    (:func:`~vesselbot_ros.geometry.candidate_tree.candidate_tree`)."""
    return Wall3D(vertices, triangles, caps, margin_m=GRID_MARGIN_M + 4.0 * h_m, root_m=3.2e-3, max_depth=4,
                  near_m=NEAR_M, deep_leaf_m=0.8e-3, far_out_m=OUT_BAND_M + 3.0 * h_m, box_m=box_m)


def build_plant_field(wall: Wall3D, h_m: float, origin_m: npt.ArrayLike, shape: tuple[int, int, int],
                      progress: ProgressFn | None = None) -> WallField3D:
    """``wall`` sampled at the plant's settings (the standard of the module docstring) on the grid of spacing
    ``h_m``, origin ``origin_m`` and ``shape`` nodes: what :func:`wall_arrays` caches, the cross-kernel build
    test fingerprints on a block and the warm-up compiles."""
    return build_wall_field3d(wall, h_m=h_m, band_m=BAND_M, out_band_m=OUT_BAND_M, refine=REFINE, origin_m=origin_m,
                              shape=shape, exact_max_depth=EXACT_DEPTH, tube=True, list_max=LIST_MAX, progress=progress)


#: The wall lookup's arrays, in the order the compiled lookup takes them (one file each in the cache's folder).
WALL_NAMES = ("head", "field", "fine", "d", "pbox", "pstart", "grid", "nodes", "index")


def wall_cache_path(name: str, key: str) -> Path:
    """The folder of a tree's cached wall lookup (``<network>-<key>.wall``: one ``.npy`` per array and
    ``stats.json``)."""
    return tree_cfd.cache_dir() / f"{name}-{key}.wall"


def _read_wall(path: Path) -> WallArrays:
    """The cached lookup, mapped (OSError / ValueError / KeyError if the folder is not a whole one of this version).

    The arrays are the files' pages, mapped copy-on-write: a run's processes that read the same tree (the plant's,
    the filter's, the controller's) share them, nothing is read before the lookup touches it, and the kernels,
    which never write them, see ordinary arrays."""
    stats = json.loads((path / "stats.json").read_text())
    if stats.get("v") != WALL_VERSION:
        raise ValueError(f"{path}: wall version {stats.get('v')!r}, not {WALL_VERSION}")
    return WallArrays(tuple(np.load(path / f"{n}.npy", mmap_mode="c") for n in WALL_NAMES), stats)


def _write_wall(path: Path, args: tuple[npt.NDArray[Any], ...], stats: dict[str, Any]) -> None:
    """Write the lookup's folder whole or not at all: built beside it, then renamed into place (a reader sees the
    folder complete or not there; a process that lost a race to write the same lookup drops its copy)."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for n, a in zip(WALL_NAMES, args, strict=True):
            np.save(tmp / f"{n}.npy", a)
        (tmp / "stats.json").write_text(json.dumps(stats))
        if path.is_dir():  # an older version's or a torn folder (one whole and current was read, not rebuilt)
            shutil.rmtree(path, ignore_errors=True)
        os.replace(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _cache_wall(path: Path, args: tuple[npt.NDArray[Any], ...], stats: dict[str, Any]) -> WallArrays:
    """Cache the lookup and hand back its mapped copy; the arrays in memory if the cache cannot take it (a full or
    read-only disk: the temporary folder goes)."""
    try:
        _write_wall(path, args, stats)
        return _read_wall(path)
    except OSError:
        return WallArrays(args, stats)


@functools.lru_cache(maxsize=8)
def wall_arrays(net: VesselNetworkParams, blood: BloodParams | None = None) -> WallArrays:
    """The compiled wall lookup's arrays of ``net``: read (mapped) from the cache, or built (tens of seconds) and
    cached."""
    fld = plant_field(net, blood)
    path = wall_cache_path(fld.name, fld.key)
    with contextlib.suppress(OSError, ValueError, KeyError):  # none, torn, foreign or older: built again
        return _read_wall(path)
    old = path.with_name(path.name + ".npz")  # the single file an earlier version cached: taken over, not rebuilt
    if old.is_file():
        with contextlib.suppress(OSError, ValueError, KeyError), np.load(old) as z:
            stats = json.loads(str(z["stats"]))
            if stats.get("v") == WALL_VERSION:
                wa = _cache_wall(path, tuple(np.ascontiguousarray(z[n]) for n in WALL_NAMES), stats)
                if isinstance(wa.args[0], np.memmap):  # moved into the folder: the old file goes
                    old.unlink()
                return wa
    check_build(net, blood)  # tens of seconds to minutes: bounded first, and one line says so
    with step(f"3-D wall field of {net.name}") as report:  # a bar when a command draws them (vesselbot_ros.progress)
        wf = build_plant_field(fld.wall, fld.h, fld.origin, fld.shape, progress=report)
    return _cache_wall(path, tuple(wf.args), {**wf.stats, "v": WALL_VERSION})  # not cached: built again next time


def wall_mesh(net: VesselNetworkParams, blood: BloodParams | None = None) -> tuple[Array, npt.NDArray[np.int64]]:
    """(vertices (n, 3) m, triangles (k, 3)) of the tree's wall (caps excluded) to draw: the flow mesh's (tens of
    thousands of triangles), within its facets' sag (up to about 20 um on the carotid's 4 mm trunk) of the
    finer one the plant computes with (:attr:`TreeField.vertices`: hundreds of thousands)."""
    fld = plant_field(net, blood)
    return fld.view_vertices, fld.view_triangles


@dataclasses.dataclass(frozen=True)
class PackedTree:
    """The 3-D plant's compiled inputs (:mod:`vesselbot_ros.physics.tree_vessel`): physics, wall, flow.

    Attributes:
        p: The packed physical parameters (:func:`~vesselbot_ros.physics.kernel.pack_params` of the physics
            with the network left out: the geometry comes from ``W``, ``F``).
        W: The wall lookup's nine arrays.  F: (nz, ny, nx, 4) float32 ``(vx, vy, vz, eta)`` per node (-, Pa s).
        fh: (7,) ``(x0, y0, z0, h, nx, ny, nz)``.
    """

    p: Array
    W: tuple[npt.NDArray[Any], ...]
    F: npt.NDArray[np.float32]
    fh: Array


@functools.lru_cache(maxsize=16)
def _flow_grid(net: VesselNetworkParams, blood: BloodParams, flow_net: VesselNetworkParams | None = None
               ) -> tuple[npt.NDArray[np.float32], Array]:
    """The flow grid (velocity, viscosity) of ``flow_net`` (default ``net``: the same tree with a flow preset's
    outlet shares, :func:`~vesselbot_ros.vessels.network.with_flow_preset`) on the wall of ``net``: the wall is
    the geometry's alone, so a preset solves and samples the flow again but builds no wall field."""
    fld = plant_field(flow_net if flow_net is not None else net, blood)
    wa = wall_arrays(net, blood)
    nx, ny, nz = fld.shape
    diam = np.asarray(wa.args[1], dtype=np.float64).reshape(nz, ny, nx, -1)[..., 4]
    F = np.empty((nz, ny, nx, 4), dtype=np.float32)  # float32 like the wall samples: half the memory of a sparse tree
    F[..., :3] = fld.velocity
    F[..., 3] = fld.viscosity(blood, diam)
    F.setflags(write=False)
    fh = np.array([*fld.origin, fld.h, nx, ny, nz], dtype=np.float64)
    return F, fh


@functools.lru_cache(maxsize=64)
def packed_tree(params: PhysicsParams) -> PackedTree:
    """The compiled inputs of ``params``, whose ``vessel.network`` is a 3-D tree (cached per frozen params).

    Raises:
        ConfigError: the network is not written in 3-D.
    """
    net = load_network(params.vessel.network)
    if not net.is_3d:
        raise ConfigError(f"physics.vessel.network: {net.name!r} gives no y_m: the planar plant takes it")
    wa = wall_arrays(net, params.blood)
    flow_net = with_flow_preset(net, params.flow.preset)  # a preset's outlet shares: the flow's own field
    F, fh = _flow_grid(net, params.blood) if flow_net is net else _flow_grid(net, params.blood, flow_net)
    return PackedTree(pack_params(planar_twin(params)), wa.args, F, fh)


def packed_vessel(physics: PhysicsParams, dims: int) -> tuple[npt.NDArray[np.float64], PackedTree | None]:
    """``(p, packed)`` of the vessel ``physics`` names, on ``dims`` axes: its packed parameters and a tree's compiled
    inputs (None in the plane).  What the plant and the models build their vessel from."""
    if dims == 3:
        k = packed_tree(physics)
        return k.p, k
    return packed_params(physics), None


def vessel_geom(p: npt.NDArray[np.float64], packed: PackedTree | None) -> Any:
    """The geometry the integrator and the compiled steps take (``physics.integrator``'s geometry edge), with the
    packed parameters ``p``: ``p`` itself in the plane, a tree's ``(p, W, F, fh)``."""
    return p if packed is None else (p, packed.W, packed.F, packed.fh)
