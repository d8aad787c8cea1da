"""Steady blood flow through a vessel network: gmsh mesh + scikit-fem Navier-Stokes.

Dimensional reduction (docs/vessels.md): the paper's navigation plane is XZ and
its plant is planar, so we solve the steady incompressible Navier-Stokes
equations in that plane (a 2-D solve, the network as a planar slab).  In a
straight branch the 2-D solution is the plane-Poiseuille parabola
``u = V_c (1 - (2 z / D)^2)``, which is exactly the tube's axial profile in its
plane of symmetry at the same centreline velocity -- the profile the analytic
plant uses (eq. (12)).  What a planar slab cannot reproduce is the 3-D flux
balance: in 2-D the flux of a branch scales as ``V_c r``, in a tube as
``V_c r^2``.  We therefore split the 2-D inflow among the outlets by Murray's
law (shares r^3 / sum r^3, ``cfd.outlet_split: murray``), by area (shares
r^2) or by given shares (``shares``: a flow preset's, of the 2-D flux), and accept that a daughter's centreline velocity is the 2-D one
(for a symmetric Murray bifurcation 0.63 of the parent's instead of 0.79 in 3-D).

Equations: ``rho (u . grad) u = -grad p + div(mu grad u)``, ``div u = 0``; Taylor-Hood P2/P1 elements on a gmsh
triangulation; mu is the Pries apparent viscosity (eq. (9), the scenario's
blood model) at the local branch diameter, element by element; Picard (Oseen)
iterations from the Stokes solution.  Boundary conditions: parabolic inflow
with centreline velocity ``cfd.inlet_centreline_velocity_m_per_s`` on the
inlet; no slip on the walls; a fully developed parabolic outflow carrying its
share of the flux on every outlet but the widest, which is traction-free
("do nothing": mu du/dn - p n = 0) and so takes what the solve delivers
(Taylor-Hood conserves the discrete flux exactly, so the outlets' balance tests
nothing; the tests integrate the *sampled* field across interior sections).

Sampling: the field is normalised to an inlet centreline velocity of 1 and
sampled with the local diameter and viscosity on a regular grid
(:class:`NetworkField`), which the compiled plant interpolates bilinearly; a
grid node outside the mesh takes the velocity of the nearest boundary point
(the profile beyond an open end, zero beside a wall).  The wall is the mesh's
boundary (:mod:`vesselbot_ros.geometry.polyline_wall`): the field stores its segments and
each grid cell's candidate segments, from which the plant computes the exact
signed distance and normal at any point (the grid's sdist/normal are those at
the nodes, for plots).  Fields are cached on disk by a hash of the geometry,
the CFD settings and the blood model (:func:`network_field`).

Shipped fields: the solve (assembly, sparse factorisation) runs through
kernels chosen by CPU (OpenBLAS's, numpy's SIMD levels: AVX-512 or AVX2), so
two machines solve the same network to fields that differ in the last bits,
and a run that touches the walls, as the III-C upper branch does, turns that
into different trajectories (wall contacts 4 against 3).  The fields of the shipped scenarios' networks are
therefore solved once and shipped (``config/cfd/<network>-<key>.npz``,
written by ``tools/ship_cfd_fields.py``): every machine runs them on the same
doubles, and :func:`network_field` reads them before the local cache.  A
network or blood model of one's own is solved and cached locally.
"""


from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.atomic_io import atomic_open
from vesselbot_ros.config import shipped_config_dir, to_mapping
from vesselbot_ros.geometry.polyline_wall import (
    WallQuery,
    cell_candidates,
    local_diameter,
    nearest_segment,
    query_points,
    wall_segments,
)
from vesselbot_ros.physics.blood_viscosity import viscosity_for
from vesselbot_ros.physics.kernel import pack_network_params, pack_params
from vesselbot_ros.physics.params import BloodParams, PhysicsParams
from vesselbot_ros.progress import ProgressFn, step
from vesselbot_ros.resources import fmt_bytes, require_fits
from vesselbot_ros.vessels.network import (
    VesselNetworkParams,
    load_network,
    require_planar,
    smooth_centreline,
    with_flow_preset,
)
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

__all__ = ["MeshedNetwork", "FlowSolution", "NetworkField", "mesh_network", "solve_flow", "sample_field",
           "network_field", "network_wall", "packed_params", "cache_dir", "shipped_field_dir", "field_file", "field_key", "FIELD_NAMES",
           "womersley_numbers"]

#: Sampled fields, in the order of :attr:`NetworkField.data` (and of the kernel's packed grid).
FIELD_NAMES = ("vx", "vz", "sdist", "nx", "nz", "diameter", "eta")
CACHE_VERSION = 7  # 5-7: exact meshed-wall geometry (geometry/polyline_wall.py), wall-disc local diameter, cap-snapped velocity

# What a new field costs, estimated before it is solved (check_field_fits); measured on a 20 mm tube of
# 1.5 mm radius (a 2-core machine, loaded): mesh 0.3 mm, 6548 triangles, solved in 6 s; mesh 0.1 mm, 78762
# triangles, 355 s and 3.3 GB; 825 thousand grid nodes sampled in 187 s and 366 MB.
#: gmsh's triangles per (lumen area / cfd.mesh_size_m^2) (10-14 measured).
TRIANGLES_PER_AREA_H2 = 14.0
#: The solve's memory per triangle (P2/P1 Taylor-Hood, the sparse LU's fill), bytes.
TRIANGLE_BYTES = 48.0 * 1024
#: The solve's time: ``SOLVE_S_REF`` at ``SOLVE_TRIANGLES_REF`` triangles, growing as their number to ``SOLVE_POWER``.
SOLVE_S_REF, SOLVE_TRIANGLES_REF, SOLVE_POWER = 6.5, 6500.0, 1.6
#: Memory and time per node of the sampling grid (bytes, s).
GRID_NODE_BYTES = 512.0
GRID_NODE_SECONDS = 2.5e-4


def cache_dir() -> Path:
    """Where sampled fields are cached: ``$VESSELBOT_CFD_CACHE`` or ``~/.cache/vesselbot_ros/cfd``."""
    env = os.environ.get("VESSELBOT_CFD_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "vesselbot_ros" / "cfd"


def shipped_field_dir() -> Path:
    """Where the fields of the shipped scenarios' networks are shipped (the shipped config's ``cfd/``)."""
    return shipped_config_dir() / "cfd"


def field_file(net: VesselNetworkParams, blood: BloodParams) -> str:
    """File name of the sampled field of ``net`` for ``blood`` (in the shipped folder or the cache)."""
    return f"{net.name}-{field_key(net, blood)}.npz"


def field_key(net: VesselNetworkParams, blood: BloodParams) -> str:
    """Cache key: sha256 of the network (geometry + CFD settings), the blood model and the code version."""
    text = json.dumps({"net": to_mapping(net), "blood": to_mapping(blood), "v": CACHE_VERSION}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


@dataclasses.dataclass
class MeshedNetwork:
    """Triangulation with boundary facets by name (``inlet``, ``outlet:<branch>``, ``wall``)."""

    points: npt.NDArray[np.float64]  # (n, 2) m
    triangles: npt.NDArray[np.int64]  # (t, 3)
    boundaries: dict[str, npt.NDArray[np.int64]]  # skfem facet indices, filled by solve_flow
    caps: dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]]  # name -> (centre, unit outward normal, radius)


def _offset_polygon(pts: npt.NDArray[np.float64], rad: npt.NDArray[np.float64], step: int) -> npt.NDArray[np.float64]:
    """Closed polygon (left side forward, right side backward) of a tube around ``pts``."""
    t = np.gradient(pts, axis=0)
    t /= np.hypot(t[:, 0], t[:, 1])[:, None]
    nrm = np.column_stack([-t[:, 1], t[:, 0]])
    idx = np.unique(np.concatenate([np.arange(0, len(pts), step), [len(pts) - 1]]))
    left = pts[idx] + rad[idx, None] * nrm[idx]
    right = pts[idx] - rad[idx, None] * nrm[idx]
    return np.concatenate([left, right[::-1]])


def mesh_network(net: VesselNetworkParams) -> MeshedNetwork:
    """Mesh the union of the branch tubes with gmsh (OpenCASCADE boolean union, flat inlet/outlet caps).

    Each branch is a polygon around its smoothed centreline; each bifurcation
    node gets a disc of the parent's end radius so the branches join without gaps.

    Raises:
        ConfigError: if ``net`` is not planar (the mesh is of the XZ plane).
    """
    require_planar(net, "the 2-D CFD")
    import gmsh  # deferred: heavy, and its wheel needs libGLU & co (tools/bootstrap.sh checks); only meshing needs it

    h = net.cfd.mesh_size_m
    caps: dict[str, tuple[Any, Any, float]] = {}
    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add(net.name)
        occ = gmsh.model.occ
        surfaces = []
        for b in net.branches:
            pts, rad, _s = smooth_centreline(b, net.smoothing, net.sample_spacing_m)
            step = max(1, int(0.5 * h / net.sample_spacing_m))
            poly = _offset_polygon(pts, rad, step)
            lc = min(h, float(rad.min()) / 3.0)  # at least 6 elements across a narrow branch
            points = [occ.addPoint(float(x), float(z), 0.0, lc) for x, z in poly]
            lines = [occ.addLine(points[i], points[(i + 1) % len(points)]) for i in range(len(points))]
            loop = occ.addCurveLoop(lines)
            surfaces.append((2, occ.addPlaneSurface([loop])))
            if b.parent == "":
                t0 = pts[1] - pts[0]
                caps["inlet"] = (pts[0].copy(), -t0 / np.hypot(*t0), float(rad[0]))
            if not net.children(b.name):
                t1 = pts[-1] - pts[-2]
                caps[f"outlet:{b.name}"] = (pts[-1].copy(), t1 / np.hypot(*t1), float(rad[-1]))
            else:
                surfaces.append((2, occ.addDisk(float(pts[-1, 0]), float(pts[-1, 1]), 0.0, float(rad[-1]), float(rad[-1]))))
        if len(surfaces) > 1:
            occ.fuse(surfaces[:1], surfaces[1:])
        occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.05 * h)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 1)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        gmsh.model.mesh.generate(2)
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        _types, _etags, enodes = gmsh.model.mesh.getElements(2)
        tri_nodes = np.asarray(enodes[0], dtype=np.int64).reshape(-1, 3)
    finally:
        gmsh.finalize()
    tags = np.asarray(node_tags, dtype=np.int64)
    xyz = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    lookup = np.full(tags.max() + 1, -1, dtype=np.int64)
    lookup[tags] = np.arange(len(tags))
    tri = lookup[tri_nodes]
    used = np.unique(tri)
    remap = np.full(len(tags), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    pts2 = xyz[used, :2]
    tri = remap[tri]
    # counter-clockwise orientation
    a, b_, c = pts2[tri[:, 0]], pts2[tri[:, 1]], pts2[tri[:, 2]]
    area = (b_[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b_[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    neg = area < 0
    tri[neg] = tri[neg][:, [0, 2, 1]]
    return MeshedNetwork(pts2, tri, {}, caps)


@dataclasses.dataclass
class FlowSolution:
    """Steady solution: skfem mesh and bases, velocity and pressure dofs, fluxes (m^2/s per unit depth)."""

    mesh: Any
    ubasis: Any
    pbasis: Any
    u: npt.NDArray[np.float64]
    p: npt.NDArray[np.float64]
    fluxes: dict[str, float]  # name -> outward flux (inlet negative)
    picard_iterations: int
    picard_change: float
    elapsed_s: float
    caps: dict[str, tuple[Any, Any, float]] = dataclasses.field(default_factory=dict)  # the mesh's open ends (MeshedNetwork.caps)


def _parabola_dofs(ubasis: Any, facets: npt.NDArray[np.int64], cap: tuple[Any, Any, float], vc: float,
                   direction: float) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """Dirichlet dofs and values of a parabolic profile on a cap (``direction`` +1 out of, -1 into the domain)."""
    centre, n_out, r = cap
    dofs = ubasis.get_dofs(facets)
    ix = dofs.nodal["u^1"], dofs.facet["u^1"]
    iz = dofs.nodal["u^2"], dofs.facet["u^2"]
    X = ubasis.doflocs
    ids_x = np.concatenate(ix)
    ids_z = np.concatenate(iz)
    loc = X[:, ids_x].T
    tang = np.array([-n_out[1], n_out[0]])
    eta = ((loc[:, 0] - centre[0]) * tang[0] + (loc[:, 1] - centre[1]) * tang[1]) / r
    prof = vc * np.clip(1.0 - eta * eta, 0.0, None) * direction
    return np.concatenate([ids_x, ids_z]), np.concatenate([prof * n_out[0], prof * n_out[1]])


def solve_flow(net: VesselNetworkParams, blood: BloodParams, meshed: MeshedNetwork | None = None,
               progress: ProgressFn | None = None) -> FlowSolution:
    """Solve the steady Navier-Stokes flow of ``net`` (see the module docstring).

    ``progress(done, total)`` is called after the mesh and assembly, after each Picard iteration and at the end
    (``done == total``: ``total`` counts the most iterations, so a converged solve jumps to it).
    """
    # deferred: scikit-fem and scipy.sparse are heavy imports (~0.3 s), paid only when a field is solved
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu
    from skfem import (
        Basis,
        BilinearForm,
        ElementTriP0,
        ElementTriP1,
        ElementTriP2,
        ElementVector,
        FacetBasis,
        Functional,
        MeshTri,
        asm,
        bmat,
        condense,
    )
    from skfem.helpers import ddot, div, dot, grad

    t0 = time.perf_counter()
    report = progress or (lambda done, total: None)
    steps = net.cfd.picard_max_iterations + 2  # mesh and assembly, the iterations, the fluxes
    report(0, steps)
    meshed = meshed or mesh_network(net)
    geom = NetworkGeometry(net)
    m = MeshTri(np.ascontiguousarray(meshed.points.T), np.ascontiguousarray(meshed.triangles.T))
    ub = Basis(m, ElementVector(ElementTriP2()), intorder=4)
    pb = ub.with_element(ElementTriP1())
    b0 = ub.with_element(ElementTriP0())
    # boundary facets by cap
    bf = m.boundary_facets()
    mid = 0.5 * (m.p[:, m.facets[0, bf]] + m.p[:, m.facets[1, bf]]).T
    assigned = np.zeros(len(bf), dtype=bool)
    for name, (centre, n_out, r) in meshed.caps.items():
        along = (mid[:, 0] - centre[0]) * n_out[0] + (mid[:, 1] - centre[1]) * n_out[1]
        across = np.abs(-(mid[:, 0] - centre[0]) * n_out[1] + (mid[:, 1] - centre[1]) * n_out[0])
        on = (np.abs(along) < 1e-3 * r) & (across <= r * (1 + 1e-6)) & ~assigned
        meshed.boundaries[name] = bf[on]
        assigned |= on
    meshed.boundaries["wall"] = bf[~assigned]
    # viscosity per element: Pries at the local branch diameter
    cent = m.p[:, m.t].mean(axis=1).T
    d_el = geom.query(cent)["diameter"]
    d_round = np.round(d_el, 12)
    eta_of = {d: viscosity_for(blood, float(d)) for d in np.unique(d_round)}
    mu_el = np.array([eta_of[d] for d in d_round])
    mu = b0.interpolate(mu_el)
    rho = blood.density_kg_per_m3

    @BilinearForm
    def viscous(u, v, w):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
        return w.mu * ddot(grad(u), grad(v))

    @BilinearForm
    def convection(u, v, w):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
        gu = grad(u)
        adv = np.einsum("j...,ij...->i...", w.wv, gu)
        return rho * dot(adv, v)

    @BilinearForm
    def divergence(u, q, w):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
        return div(u) * q

    A_visc = asm(viscous, ub, mu=mu)
    B = asm(divergence, ub, pb)
    nu, npr = A_visc.shape[0], B.shape[0]
    report(1, steps)
    # Dirichlet data
    vc_in = net.cfd.inlet_centreline_velocity_m_per_s
    r_in = meshed.caps["inlet"][2]
    q_in = 4.0 / 3.0 * vc_in * r_in  # 2-D flux of the inlet parabola (m^2/s)
    outlets = [k for k in meshed.caps if k.startswith("outlet:")]
    radii = {k: meshed.caps[k][2] for k in outlets}
    power = 3.0 if net.cfd.outlet_split == "murray" else 2.0
    total = sum(r ** power for r in radii.values())
    given = dict(zip(net.cfd.share_outlets, net.cfd.outlet_shares))  # outlet_split: shares (a flow preset's)
    free = max(outlets, key=lambda k: (radii[k], outlets.index(k)))  # the widest (last among equals) is traction-free
    fixed_dofs: list[npt.NDArray[np.int64]] = []
    fixed_vals: list[npt.NDArray[np.float64]] = []
    wall_dofs = ub.get_dofs(meshed.boundaries["wall"]).all()
    fixed_dofs.append(wall_dofs)
    fixed_vals.append(np.zeros(len(wall_dofs)))
    d, v = _parabola_dofs(ub, meshed.boundaries["inlet"], meshed.caps["inlet"], vc_in, -1.0)
    fixed_dofs.append(d)
    fixed_vals.append(v)
    for k in outlets:
        if k == free:
            continue
        share = given[k.removeprefix("outlet:")] if given else radii[k] ** power / total
        vc_k = 3.0 * share * q_in / (4.0 * radii[k])
        d, v = _parabola_dofs(ub, meshed.boundaries[k], meshed.caps[k], vc_k, 1.0)
        fixed_dofs.append(d)
        fixed_vals.append(v)
    x = np.zeros(nu + npr)
    # the inlet/outlet values win over the wall's zero at the shared corner nodes
    for dd, vv in zip(fixed_dofs, fixed_vals):
        x[dd] = vv
    D = np.unique(np.concatenate(fixed_dofs))
    corner_zero = np.intersect1d(wall_dofs, np.concatenate(fixed_dofs[1:]))
    x[corner_zero] = 0.0
    u = np.zeros(nu)
    change = np.inf
    it = 0
    for it in range(1, net.cfd.picard_max_iterations + 1):
        if it == 1:
            A = A_visc
        else:
            A = A_visc + asm(convection, ub, wv=ub.interpolate(u))
        K = bmat([[A, -B.T], [-B, None]], "csc")
        Kc, rhs, xI, interior = condense(K, np.zeros(nu + npr), x=x, D=D)
        sol = xI.copy()
        sol[interior] = splu(sp.csc_matrix(Kc)).solve(rhs)
        u_new = sol[:nu]
        change = float(np.max(np.abs(u_new - u)) / max(np.max(np.abs(u_new)), 1e-300))
        u = u_new
        pr = sol[nu:]
        report(1 + it, steps)
        if it > 1 and change < net.cfd.picard_tol:
            break
    flux_form = Functional(lambda w: dot(w["u"], w.n))
    fluxes = {}
    for name in ["inlet", *outlets]:
        fb = FacetBasis(m, ub.elem, facets=meshed.boundaries[name], intorder=6)
        fluxes[name] = float(asm(flux_form, fb, u=fb.interpolate(u)))
    report(steps, steps)
    return FlowSolution(m, ub, pb, u, pr, fluxes, it, change, time.perf_counter() - t0, dict(meshed.caps))


@dataclasses.dataclass(frozen=True)
class NetworkField:
    """Fields sampled on a regular grid and the meshed wall (the plant's lookup table).

    Attributes:
        x0_m, z0_m: Grid origin (m).  h_m: spacing (m).  nx, nz: points per axis.
        data: (7, nz, nx) float64 in :data:`FIELD_NAMES` order: velocity
            normalised to an inlet centreline velocity of 1 (-), signed distance
            (m, > 0 inside), unit inward normal (-), local diameter (m), viscosity (Pa s).
            The distance and normal at the nodes are the exact ones of the meshed wall
            (:mod:`vesselbot_ros.geometry.polyline_wall`); the plant computes them exactly at any point
            from the three wall arrays below and reads only the velocity, diameter and viscosity here.
        meta: Solve statistics and provenance (JSON-able).
        wall_segments: (k, 4) wall segments ``(ax, az, bx, bz)`` (m), lumen on the left, caps left
            out and each wall end continued beyond its cap (:func:`vesselbot_ros.geometry.polyline_wall.wall_segments`).
        cell_offsets: ((nx-1)(nz-1)+1,) int64, CSR offsets of the grid cells' candidate segments.
        cell_index: (total,) int64, the candidate segments of cell ``j (nx-1) + i``.
    """

    x0_m: float
    z0_m: float
    h_m: float
    nx: int
    nz: int
    data: npt.NDArray[np.float64]
    meta: dict[str, Any]
    wall_segments: npt.NDArray[np.float64] = dataclasses.field(default_factory=lambda: np.zeros((0, 4)))
    cell_offsets: npt.NDArray[np.int64] = dataclasses.field(default_factory=lambda: np.zeros(1, dtype=np.int64))
    cell_index: npt.NDArray[np.int64] = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def field(self, name: str) -> npt.NDArray[np.float64]:
        """(nz, nx) grid of ``name`` (one of :data:`FIELD_NAMES`)."""
        return self.data[FIELD_NAMES.index(name)]

    def grid(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """(x (nx,), z (nz,)) grid coordinates (m)."""
        x = np.asarray(self.x0_m + self.h_m * np.arange(self.nx), dtype=np.float64)
        return x, np.asarray(self.z0_m + self.h_m * np.arange(self.nz), dtype=np.float64)

    def save(self, path: Path) -> None:
        """Write atomically (temporary file, then rename) as compressed npz."""
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_open(path, "wb") as fh:
            np.savez_compressed(fh, head=np.array([self.x0_m, self.z0_m, self.h_m, self.nx, self.nz]),
                                data=self.data, meta=np.array(json.dumps(self.meta)),
                                wall_segments=self.wall_segments, cell_offsets=self.cell_offsets,
                                cell_index=self.cell_index)

    @classmethod
    def load(cls, path: Path) -> NetworkField:
        """Read a field written by :meth:`save`."""
        with np.load(path) as z:
            head = z["head"]
            data = np.ascontiguousarray(z["data"], dtype=np.float64)
            meta = json.loads(str(z["meta"]))
            segs = np.ascontiguousarray(z["wall_segments"], dtype=np.float64)
            off = np.ascontiguousarray(z["cell_offsets"], dtype=np.int64)
            idx = np.ascontiguousarray(z["cell_index"], dtype=np.int64)
        return cls(float(head[0]), float(head[1]), float(head[2]), int(head[3]), int(head[4]), data, meta, segs, off, idx)


def _p2_velocity(sol: FlowSolution, q: npt.NDArray[np.float64], e: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
    """(k, 2) P2 velocity at points q (k, 2) in elements e (k,) (barycentric, element by element)."""
    m = sol.mesh
    out = np.zeros((len(q), 2))
    P = m.p[:, m.t[:, e]]  # (2, 3, k)
    a, b, c = P[:, 0].T, P[:, 1].T, P[:, 2].T
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    l1 = ((q[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (q[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) / det
    l2 = ((b[:, 0] - a[:, 0]) * (q[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (q[:, 0] - a[:, 0])) / det
    l0 = 1.0 - l1 - l2
    # P2 shape functions: vertices, then the edges (0,1), (1,2), (0,2) (skfem's MeshTri facet order)
    N = np.stack([l0 * (2 * l0 - 1), l1 * (2 * l1 - 1), l2 * (2 * l2 - 1), 4 * l0 * l1, 4 * l1 * l2, 4 * l0 * l2])
    for comp, (uc, sb) in enumerate(sol.ubasis.split(sol.u)):
        out[:, comp] = (N * uc[sb.element_dofs[:, e]]).sum(axis=0)
    return out


def interpolate_velocity(sol: FlowSolution, pts: npt.NDArray[np.float64], tri: Any) -> npt.NDArray[np.float64]:
    """(m, 2) P2 velocity at points (m, 2); outside the mesh, the velocity at the nearest boundary point.

    Evaluated element by element from barycentric coordinates (skfem's
    ``probes`` builds a dense points x elements array, too big for a grid).
    A point outside the mesh takes the velocity of the nearest point of the
    mesh's boundary, in the element of that boundary edge: zero beyond a wall,
    the inflow/outflow profile beyond a cap (a grid node just outside an open
    end then carries the profile there instead of a zero that bilinear
    interpolation would smear into the lumen).
    """
    m = sol.mesh
    el = tri.get_trifinder()(pts[:, 0], pts[:, 1])
    out = np.zeros((len(pts), 2))
    ok = el >= 0
    out[ok] = _p2_velocity(sol, pts[ok], el[ok])
    if (~ok).any():
        t = m.t.T
        e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        owner = np.tile(np.arange(len(t)), 3)
        key = np.sort(e, axis=1)
        _u, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        bnd = cnt[inv.ravel()] == 1
        segs = np.ascontiguousarray(np.column_stack([m.p[:, e[bnd, 0]].T, m.p[:, e[bnd, 1]].T]))
        k, foot = nearest_segment(np.ascontiguousarray(pts[~ok]), segs)
        out[~ok] = _p2_velocity(sol, foot, owner[bnd][k])
    return out


def sample_field(net: VesselNetworkParams, blood: BloodParams, sol: FlowSolution) -> NetworkField:
    """Sample ``sol`` and the meshed wall's geometry on the regular grid of ``net.cfd``."""
    from matplotlib.tri import Triangulation  # deferred: matplotlib is heavy, needed only to sample a new field

    geom = NetworkGeometry(net)
    h = net.cfd.grid_spacing_m
    xmin, xmax, zmin, zmax = geom.bbox
    mg = net.cfd.grid_margin_m
    # grid nodes on multiples of h, so a centreline at z = 0 lies on grid nodes
    x0 = math.floor((xmin - mg) / h) * h
    z0 = math.floor((zmin - mg) / h) * h
    nx = int(math.ceil((xmax + mg - x0) / h)) + 1
    nz = int(math.ceil((zmax + mg - z0) / h)) + 1
    X, Z = np.meshgrid(x0 + h * np.arange(nx), z0 + h * np.arange(nz))
    pts = np.column_stack([X.ravel(), Z.ravel()])
    m = sol.mesh
    vel = interpolate_velocity(sol, pts, Triangulation(m.p[0], m.p[1], m.t.T))
    vc_in = net.cfd.inlet_centreline_velocity_m_per_s
    # the meshed wall, rounded to float32 like every stored number (the candidate lists are built on the
    # rounded segments, so they are exact for what the plant computes with); each wall end is continued
    # beyond its cap past the grid's edge (the grid reaches (r + margin) sqrt(2) beyond a cap at most)
    ext = 2.0 * (max(c[2] for c in sol.caps.values()) + mg) + 4.0 * h
    segs, _caps = wall_segments(m.p.T, m.t.T, sol.caps, ext)
    segs = np.ascontiguousarray(segs.astype(np.float32).astype(np.float64))
    off, idx = cell_candidates(segs, x0, z0, h, nx, nz)
    q = query_points(pts, segs.ravel(), off.astype(np.float64), idx.astype(np.float64), x0, z0, h, nx, nz)
    # local diameter: the largest inscribed disc touching the wall where the point's nearest wall point is
    # (geometry/polyline_wall.py); it jumps where the nearest wall changes in a junction, and the wall moves out by
    # D eps(t) / 2 with the pulsation (13), so it (and the viscosity that follows it) is smoothed with a
    # Gaussian of cfd.diameter_smoothing_m (a constant field, the straight vessel, stays exactly constant)
    segs_f, off_f, idx_f = segs.ravel(), off.astype(np.float64), idx.astype(np.float64)
    diam = local_diameter(lambda pp: query_points(np.ascontiguousarray(pp), segs_f, off_f, idx_f, x0, z0, h, nx, nz),
                           x0, z0, h, nx, nz)
    dr = np.round(diam, 9)
    d_unique, inv = np.unique(dr, return_inverse=True)
    eta = np.array([viscosity_for(blood, float(d)) for d in d_unique])[inv.ravel()].reshape(nz, nx)
    sig = net.cfd.diameter_smoothing_m / h
    if sig > 0:
        from scipy.ndimage import gaussian_filter  # deferred: scipy.ndimage is heavy, needed only to sample

        diam = np.where(np.ptp(diam) > 0, gaussian_filter(diam, sig, mode="nearest"), diam)
        eta = np.where(np.ptp(eta) > 0, gaussian_filter(eta, sig, mode="nearest"), eta)
    data = np.stack([
        vel[:, 0] / vc_in, vel[:, 1] / vc_in, q[:, 0], q[:, 1], q[:, 2], diam.ravel(), eta.ravel(),
    ]).reshape(len(FIELD_NAMES), nz, nx)
    # stored in single precision: the sparse LU's last bits depend on the CPU's BLAS kernel; rounded to
    # float32 (7 digits: 0.1 nm in the distance, 1e-7 of V_f) the field is the same on every machine
    data = data.astype(np.float32).astype(np.float64)
    meta = {"network": net.name, "fluxes_m2_per_s": sol.fluxes, "picard_iterations": sol.picard_iterations,
            "picard_change": sol.picard_change, "solve_s": sol.elapsed_s, "n_triangles": int(m.t.shape[1]),
            "n_dofs": int(sol.u.size + sol.p.size), "n_wall_segments": int(len(segs)),
            "n_cell_candidates": int(idx.size), "n_wall_extensions": 2 * len(sol.caps)}
    return NetworkField(x0, z0, h, nx, nz, np.ascontiguousarray(data), meta, segs, off, idx)


def field_estimate(net: VesselNetworkParams) -> tuple[float, float]:
    """(triangles of the mesh, nodes of the sampling grid) a new field of ``net`` would have (module constants)."""
    area = 0.0
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for b in net.branches:
        pts = np.column_stack([b.x_m, b.z_m]).astype(np.float64)
        rad = b.radii()
        seg = np.hypot(*np.diff(pts, axis=0).T)
        area += float((seg * (rad[1:] + rad[:-1])).sum())  # 2 r per unit length
        lo = np.minimum(lo, (pts - rad[:, None]).min(axis=0))
        hi = np.maximum(hi, (pts + rad[:, None]).max(axis=0))
    c = net.cfd
    triangles = TRIANGLES_PER_AREA_H2 * area / c.mesh_size_m ** 2
    nodes = float(np.prod((hi - lo + 2.0 * c.grid_margin_m) / c.grid_spacing_m + 2.0))
    return triangles, nodes


def check_field_fits(net: VesselNetworkParams) -> tuple[float, float]:
    """Refuse, before it starts, a new field of ``net`` whose solve or sampling would not fit (memory, time).

    Returns:
        (triangles, grid nodes) estimated.

    Raises:
        ConfigError: one line naming ``cfd.mesh_size_m`` or ``cfd.grid_spacing_m``, its value and the estimate.
    """
    triangles, nodes = field_estimate(net)
    c = net.cfd
    seconds = SOLVE_S_REF * (triangles / SOLVE_TRIANGLES_REF) ** SOLVE_POWER
    require_fits("cfd.mesh_size_m", c.mesh_size_m, TRIANGLE_BYTES * triangles, seconds,
                 what=f"the 2-D flow solve of network {net.name!r} ({triangles:.3g} triangles)",
                 hint="raise cfd.mesh_size_m")
    require_fits("cfd.grid_spacing_m", c.grid_spacing_m, GRID_NODE_BYTES * nodes, GRID_NODE_SECONDS * nodes,
                 what=f"the sampled field of network {net.name!r} ({nodes:.3g} grid nodes)",
                 hint="raise cfd.grid_spacing_m")
    return triangles, nodes


def network_field(net: VesselNetworkParams, blood: BloodParams, *, refresh: bool = False) -> NetworkField:
    """The sampled field of ``net`` for ``blood``: shipped, cached, or solved, sampled and cached.

    ``refresh`` solves again whatever is shipped or cached (and caches the result).

    Raises:
        ConfigError: if ``net`` is not planar (this solve is 2-D).
    """
    require_planar(net, "the 2-D CFD")
    name = field_file(net, blood)
    path = cache_dir() / name
    for found in () if refresh else (shipped_field_dir() / name, path):
        if found.is_file():
            try:
                return NetworkField.load(found)
            except (OSError, ValueError, KeyError):
                pass  # a torn or foreign file: solve again
    triangles, nodes = check_field_fits(net)  # before any work: one line if it does not fit
    print(f"meshing {net.name} (about {triangles:.3g} triangles, est. "
          f"{fmt_bytes(max(TRIANGLE_BYTES * triangles, GRID_NODE_BYTES * nodes))}; solved once, then cached)",
          file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    with step(f"2-D flow of {net.name}") as report:  # a bar when a command draws them (vesselbot_ros.progress)
        steps = [1]

        def solving(done: int, total: int) -> None:  # the solve's steps, then one for the sampling
            steps[0] = total + 1
            report(done, steps[0])

        sol = solve_flow(net, blood, progress=solving)
        field = sample_field(net, blood, sol)
        report(steps[0], steps[0])
    field.meta["total_s"] = time.perf_counter() - t0
    field.save(path)
    return field


@functools.lru_cache(maxsize=16)
def network_wall(net: VesselNetworkParams, blood: BloodParams | None = None) -> Any:
    """The meshed wall of ``net`` as :class:`vesselbot_ros.geometry.polyline_wall.WallQuery` (exact distance and normal).

    The wall depends on the geometry and mesh settings only, not on the blood model; it is read from
    the field of ``blood`` (default :class:`BloodParams`, the shipped scenarios' blood), so a wall of a
    shipped network costs no solve.  Cached per (frozen) network and blood.
    """
    return WallQuery(network_field(net, blood if blood is not None else BloodParams()))


@functools.lru_cache(maxsize=64)
def packed_params(params: PhysicsParams) -> npt.NDArray[np.float64]:
    """The kernel's parameter vector of ``params``, a network's CFD field resolved and packed in.

    The one step that may solve the CFD (:func:`network_field`: shipped, cached, or solved and cached);
    :func:`vesselbot_ros.physics.kernel.pack_params` never does, and refuses a network.  A straight
    vessel's vector is ``pack_params(params)``.  Cached per (hashable, frozen) params; read-only.
    """
    if not params.vessel.network:
        return pack_params(params)
    net = with_flow_preset(load_network(params.vessel.network), params.flow.preset)  # a preset's outlet shares
    return pack_network_params(params, network_field(net, params.blood))


def womersley_numbers(net: VesselNetworkParams, blood: BloodParams, omega_rad_per_s: float) -> dict[str, float]:
    """Womersley number alpha = R sqrt(omega rho / eta(D)) of each branch (at its widest radius), by name."""
    out = {}
    for b in net.branches:
        r = float(max(b.radius_m))
        eta = viscosity_for(blood, 2.0 * r)
        out[b.name] = r * math.sqrt(omega_rad_per_s * blood.density_kg_per_m3 / eta)
    return out
