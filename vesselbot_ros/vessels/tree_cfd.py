"""Steady 3-D blood flow through a vessel tree: scikit-fem Navier-Stokes on the tree's gmsh solid mesh.

Taylor-Hood P2/P1 with the Pries viscosity element by element, a Poiseuille inflow, no slip, and outlets left
traction-free (the tree splits the flow itself) or given Murray's or the area's shares; one algebraic multigrid
hierarchy and flexible GMRES under Picard iterations.  The mesh is :mod:`vesselbot_ros.vessels.tree_mesh`'s; the
equations, the solver, the validation and the costs: docs/vessels.md, "CFD in 3-D".
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
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
from vesselbot_ros.vessels.network import VesselNetworkParams
from vesselbot_ros.vessels.tree_mesh import Meshed3D, Tree3D, _any_normal, _unit, local_diameter, mesh_tree

__all__ = [
    "Flow3DSettings",
    "FlowSolution3D",
    "settings_from_network",
    "solve_tree",
    "evaluate",
    "sample_grid",
    "section_flux",
    "cache_dir",
    "solution_key",
    "settings_mapping",
    "solve_tree_cached",
]

CACHE_VERSION = 1


@dataclasses.dataclass(frozen=True)
class Flow3DSettings:
    """How a 3-D tree is meshed and solved.

    Attributes:
        inlet_centreline_velocity_m_per_s: Centreline velocity of the Poiseuille inflow (m/s).
        mesh_size_m: Largest tetrahedron edge (m), the lumen's interior.
        wall_elements_per_circle: Elements around a circumference of the wall (gmsh curvature
            sizing): the narrow branches' resolution (the polygonal section's area is short of the
            circle's by about (2 pi / N)^2 / 6: 0.64 % at N = 32).
        outlets: ``natural`` (every outlet traction-free), ``murray`` (r^3 shares), ``area`` (r^2) or
            ``shares`` (``outlet_shares``).
        outlet_shares: With ``outlets: shares``: ``(outlet branch, share)`` of every outlet, the shares summing
            to 1 (a flow preset's); left out of the cache key when empty.
        picard_max_iterations: Cap on the Picard (Oseen) iterations.
        picard_tol: Relative change of the velocity (max norm) at which Picard stops.
        linear_tol: Relative residual of each Oseen solve (flexible GMRES).
        linear_max_iterations: Cap on the GMRES iterations of one Oseen solve.
    """

    inlet_centreline_velocity_m_per_s: float = 0.025
    mesh_size_m: float = 3.0e-4
    wall_elements_per_circle: int = 24
    outlets: Literal["natural", "murray", "area", "shares"] = "natural"
    picard_max_iterations: int = 30
    picard_tol: float = 1.0e-7
    linear_tol: float = 1.0e-10
    linear_max_iterations: int = 600
    outlet_shares: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        if self.outlets not in ("natural", "murray", "area", "shares"):
            raise ConfigError(f"outlets must be one of ['natural', 'murray', 'area', 'shares'], got {self.outlets!r}")
        if (self.outlets == "shares") != bool(self.outlet_shares):
            raise ConfigError(f"outlet_shares go with outlets: shares and only with it, got outlets={self.outlets!r}, "
                              f"outlet_shares={list(self.outlet_shares)}")
        for f in ("inlet_centreline_velocity_m_per_s", "mesh_size_m", "picard_tol", "linear_tol"):
            v = getattr(self, f)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{f} must be positive, got {v!r}")
        if self.wall_elements_per_circle < 6:
            raise ConfigError(f"wall_elements_per_circle must be >= 6, got {self.wall_elements_per_circle!r}")


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
    """Solve the steady Navier-Stokes flow through ``tree`` (docs/vessels.md, "CFD in 3-D").

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
    meshed = meshed or mesh_tree(tree, settings.mesh_size_m, settings.wall_elements_per_circle)
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
        given = dict(settings.outlet_shares)  # outlets: shares (a flow preset's)
        if given and set(given) != {k.removeprefix("outlet:") for k in outlets}:
            raise ConfigError(f"outlet_shares must name every outlet of the tree {sorted(k.removeprefix('outlet:') for k in outlets)}, "
                              f"got {sorted(given)}")
        widest = max(outlets, key=lambda k: (radii[k], outlets.index(k)))
        free = [widest]
        for k in outlets:
            if k == widest:
                continue
            dk, prof = cap_values(k)
            share = given[k.removeprefix("outlet:")] if given else radii[k] ** power / total
            scale = share * q_in / discrete_flux(k, dk, prof)
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


def settings_mapping(settings: Flow3DSettings) -> dict[str, Any]:
    """``settings`` as a plain mapping for a cache key: ``outlet_shares`` left out when empty (the keys of the
    solutions and fields made before it existed stay theirs)."""
    out = dataclasses.asdict(settings)
    if not settings.outlet_shares:
        del out["outlet_shares"]
    return out


def solution_key(tree: Tree3D, settings: Flow3DSettings, blood: BloodParams) -> str:
    """Cache key: sha256 of the tree, the settings, the blood model and the cache version."""
    text = json.dumps({"tree": dataclasses.asdict(tree), "settings": settings_mapping(settings),
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
