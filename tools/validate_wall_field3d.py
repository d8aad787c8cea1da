#!/usr/bin/env python3
"""Validate the sampled 3-D wall (vesselbot_ros/geometry/field_build.py) against the exact query and analytic walls.

Meshes the reference solids of tools/validate_wall3d.py with gmsh (a cylinder R = 1.5 mm, a bent tube R =
1.5 mm round a 6 mm bend over 90 deg, a Y: parent 1.5 mm, daughters 1.2 mm at +-35 deg), samples each wall
on a grid of spacing ``--h-mm`` and prints, per geometry:

* the grid (nodes, memory), the build time (sampling, local diameter, flags) and the flagged cells (by the
  corners' normal spread, by a test point; their fraction of all cells and of the lumen's);
* at random points within 1 mm of the wall, inside and outside, anywhere in the grid (junction, crease and
  caps included): the lookup against the exact query (max distance error um, max normal error deg);
* against the analytic wall (cylinder and bent tube: 0.5 mm or more from the caps; the Y's branches 3 mm or
  more from the node and 0.5 mm or more off a daughter's crease, as tools/validate_wall3d.py);
* the sign against the exact query more than 5 um from the wall, and in the Y against the analytic union
  of its cylinders and ball more than 5 um from every solid's surface;
* the local diameter against 2 R in the cylinder's and the bent tube's lumen (0.5 mm or more from the caps).

Standard: distance <= 5 um, normal <= 2 deg within 1 mm of the wall.

``--shipped`` validates the shipped trees' walls instead, as the 3-D plant builds them
(:func:`vesselbot_ros.vessels.tree_field.wall_arrays`: the standard held within 1 mm of the wall in the lumen
and 0.1 mm outside it; model cells; the exact query pruned), per tree:

* at random points in the band, inside and outside, the lookup against the exact query of the same (fine)
  surface: max distance error, max normal error (all points, and leaving out the ill-conditioned ones, where
  the exact normal itself turns by more than 2 deg within 5 um -- a point on or within micrometres of a
  medial surface: a vessel's axis, a junction's bisector -- and how many points exceed 2 deg there), sign
  mismatches more than 5 um from the wall, the share of the points the exact query answers (and a list cell's
  scan);
* the fine surface against the analytic one where the tree gives it, its straight round branches (1.5 radii or
  more from their ends, the vertices and triangle centroids nearest that branch): the vertices' radius error
  and the centroids' (the facets' sag);
* the wall arrays' sizes.

Usage: ``python tools/validate_wall_field3d.py [--h-mm 0.1] [--mesh-mm 0.1] [--float64] [--points 200000] [--refine 1]``
or ``python tools/validate_wall_field3d.py --shipped [--tree NAME] [--points 200000]``
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import numpy.typing as npt

from vesselbot_ros.geometry.field_build import WallField3D, build_wall_field3d
from vesselbot_ros.geometry.field_lookup import NODE_STRIDE, field_points3d
from vesselbot_ros.geometry.fixtures import Y_BRANCHES, bent_tube_wall, cylinder_wall, y_solids, y_wall
from vesselbot_ros.geometry.surface_wall import Wall3D

Array = npt.NDArray[np.float64]
R = 1.5e-3
BEND = 6e-3


def angle_deg(a: Array, b: Array) -> Array:
    """Angle (deg) between rows of unit vectors."""
    return np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0)))


def near_wall_points(field: WallField3D, n: int, rng: np.random.Generator, band_m: float = 1e-3) -> Array:
    """About ``n`` random points of the grid's box within ``band_m`` of the wall (exact query), inside and outside."""
    o = field.head[:3]
    top = o + field.head[3] * (np.array(field.shape) - 1)
    out = []
    got = 0
    while got < n:
        q = rng.uniform(o, top, size=(4 * n, 3))
        s = field.wall.query(q)["sdist"]
        q = q[np.abs(s) <= band_m]
        out.append(q)
        got += len(q)
    return np.ascontiguousarray(np.concatenate(out)[:n])


def cylinder_reference(q: Array, length_m: float) -> tuple[Array, Array, Array]:
    """(keep: 0.5 mm or more from the caps, signed distance m, inward normal) of the cylinder along +x."""
    rho = np.hypot(q[:, 1], q[:, 2])
    keep = (q[:, 0] > 0.5e-3) & (q[:, 0] < length_m - 0.5e-3) & (rho > 1e-9)
    n = -np.column_stack([0 * rho, q[:, 1], q[:, 2]]) / np.maximum(rho, 1e-300)[:, None]
    return keep, R - rho, n


def torus_reference(q: Array, angle_rad: float) -> tuple[Array, Array, Array]:
    """(keep: azimuth 10 deg or more from the ends, signed distance m, inward normal) of the bent tube."""
    ph = np.arctan2(q[:, 1], q[:, 0])
    er = np.column_stack([np.cos(ph), np.sin(ph), 0 * ph])
    c = BEND * er
    dvec = q - c
    rho = np.linalg.norm(dvec, axis=1)
    keep = (ph > math.radians(10)) & (ph < angle_rad - math.radians(10)) & (rho > 1e-9)
    return keep, R - rho, -dvec / np.maximum(rho, 1e-300)[:, None]


def y_reference(q: Array) -> tuple[Array, Array, Array]:
    """(keep: the branch standard's region, signed distance m, inward normal) of the Y's nearest branch wall.

    Kept: 3 mm or more from the node along the branch's axis, not beyond a cap, the foot 0.5 mm or more
    from the other solids' surfaces (away from the crease).
    """
    best = np.full(len(q), -np.inf)
    nrm = np.zeros_like(q)
    along = np.zeros(len(q))
    for s, u, L, r in Y_BRANCHES:
        t = (q - s) @ u
        foot = s + np.clip(t, 0, L)[:, None] * u
        d = np.linalg.norm(q - foot, axis=1)
        val = r - d
        take = val > best
        best[take] = val[take]
        nrm[take] = -((q - foot) / np.maximum(d, 1e-300)[:, None])[take]
        along[take] = (np.where(s[0] < 0, L - t, t))[take]
    foot = q - best[:, None] * nrm
    keep = along >= 3e-3
    for s, u, L, r in Y_BRANCHES:
        t = (q - s) @ u
        keep &= (t < L - 0.5e-3) if s[0] >= 0 else (t > 0.5e-3)
        tf = (foot - s) @ u
        dfoot = np.linalg.norm(foot - s - np.clip(tf, 0, L)[:, None] * u, axis=1)
        keep &= ~((dfoot < r + 0.5e-3) & (np.abs(dfoot - r) > 1e-9) & (np.linalg.norm(foot, axis=1) < 3.5e-3))
    return keep, best, nrm


def y_union(q: Array) -> tuple[Array, Array]:
    """(inside the analytic union of the Y's cylinders and ball, min over the solids of |signed distance| m)."""
    inside, near, _beyond = y_solids(q)
    return inside, near


def y_beyond_caps(q: Array) -> Array:
    """Points beyond (or within 50 um of) a cap of the Y, where its lumen continues past the union."""
    out = np.zeros(len(q), dtype=bool)
    for s, u, L, _r in Y_BRANCHES:
        t = (q - s) @ u
        out |= (t > L - 5e-5) if s[0] >= 0 else (t < 5e-5)
    return out


def check(field: WallField3D, name: str, n: int, rng: np.random.Generator) -> dict[str, float]:
    """Every figure of the module docstring for one geometry."""
    row: dict[str, float] = dict(field.stats)
    flags = field.flags()
    nx, ny, nz = field.shape
    s_nodes = field.field.reshape(nz, ny, nx, NODE_STRIDE)[:, :, :, 0]
    lumen_cell = (s_nodes[:-1, :-1, :-1] > 0)
    row["flagged_fraction_lumen"] = float((flags[lumen_cell] != 0).mean())
    row["exact_fraction_near_wall_points"] = float(field.exact_mask(near_wall_points(field, 20000, rng)).mean())
    q = near_wall_points(field, n, rng)
    r = field.query(q)
    e = field.wall.query(q)
    row["points"] = float(len(q))
    row["vs_exact_dist_um"] = float(np.abs(r["sdist"] - e["sdist"]).max() * 1e6)
    ang = angle_deg(r["normal"], e["normal"])
    row["vs_exact_normal_deg"] = float(ang.max())
    row["vs_exact_normal_deg_p99"] = float(np.percentile(ang, 99))
    far = np.abs(e["sdist"]) > 5e-6
    row["sign_mismatches_vs_exact"] = float(((r["sdist"] > 0) != (e["sdist"] > 0))[far].sum())
    if name == "cylinder":
        keep, s_true, n_true = cylinder_reference(q, 8e-3)
    elif name == "bent tube":
        keep, s_true, n_true = torus_reference(q, 0.5 * math.pi)
    else:
        keep, s_true, n_true = y_reference(q)
        inside, near = y_union(q)
        ok = (near > 5e-6) & ~y_beyond_caps(q)
        row["sign_points_vs_union"] = float(ok.sum())
        row["sign_mismatches_vs_union"] = float(((r["sdist"] > 0) != inside)[ok].sum())
    row["analytic_points"] = float(keep.sum())
    row["vs_analytic_dist_um"] = float(np.abs(r["sdist"] - s_true)[keep].max() * 1e6)
    ang = angle_deg(r["normal"], n_true)[keep]
    row["vs_analytic_normal_deg"] = float(ang.max())
    row["vs_analytic_normal_deg_p99"] = float(np.percentile(ang, 99))
    row["exact_vs_analytic_normal_deg"] = float(angle_deg(e["normal"], n_true)[keep].max())
    if name != "Y":
        lumen = keep & (s_true > 0)
        row["diameter_err_um"] = float(np.abs(r["diameter"][lumen] - 2 * R).max() * 1e6)
    return row


def validate(h_m: float = 0.1e-3, mesh_m: float = 0.1e-3, dtype: type = np.float32, n: int = 200_000,
             seed: int = 7, refine: int = 1) -> dict[str, dict[str, float]]:
    """The tables, by geometry."""
    rng = np.random.default_rng(seed)
    out: dict[str, dict[str, float]] = {}
    for name, make in (("cylinder", lambda: cylinder_wall(h_m=mesh_m)), ("bent tube", lambda: bent_tube_wall(h_m=mesh_m)),
                       ("Y", lambda: y_wall(h_m=mesh_m))):
        v, t, caps, _nv = make()
        t0 = time.perf_counter()
        wall = Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * h_m)
        t1 = time.perf_counter()
        field = build_wall_field3d(wall, h_m=h_m, dtype=dtype, refine=refine)
        row = {"triangles": float(len(t)), "wall3d_s": t1 - t0}
        row.update(check(field, name, n, rng))
        out[name] = row
    return out


def straight_branches(net: object) -> list[tuple[str, Array, Array, float]]:
    """(name, start, end, radius) of the tree's straight branches of one radius (their wall is a cylinder)."""
    from vesselbot_ros.vessels import tree_mesh  # deferred: only the shipped trees' section needs the tree mesh module

    out = []
    for b in tree_mesh.tree_from_network(net).branches:  # type: ignore[arg-type]
        pts, rad = b.points(), b.radii()
        if tree_mesh._collinear(pts) and tree_mesh._constant(rad):
            out.append((b.name, pts[0], pts[-1], float(rad[0])))
    return out


def nearest_branch(net: object, pts: Array) -> list[str]:
    """Per point the branch whose tube wall (its densified centreline and radii) is nearest."""
    from vesselbot_ros.vessels import tree_mesh  # deferred: only the shipped trees' section needs the tree mesh module

    best = np.full(len(pts), np.inf)
    name = np.full(len(pts), "", dtype=object)
    for b in tree_mesh.tree_from_network(net).branches:  # type: ignore[arg-type]
        dense, rad = tree_mesh._densify(b.points(), b.radii(), 0.02 * float(b.radii().min()))
        for a0 in range(0, len(pts), 20000):
            q = pts[a0:a0 + 20000]
            dd = np.linalg.norm(q[:, None, :] - dense[None, ::4, :], axis=2)
            k = np.argmin(dd, axis=1)
            gap = np.abs(dd[np.arange(len(q)), k] - rad[::4][k])
            take = gap < best[a0:a0 + 20000]
            best[a0:a0 + 20000][take] = gap[take]
            name[a0:a0 + 20000][take] = b.name
    return list(name)


def shipped(name: str, n: int, seed: int = 11) -> dict[str, float]:
    """The figures of ``--shipped`` for one tree (module docstring)."""
    from vesselbot_ros.physics.params import BloodParams  # deferred: only the shipped trees' section needs them
    from vesselbot_ros.vessels import tree_field as pf
    from vesselbot_ros.vessels.network import load_network

    net = load_network(name)
    fld = pf.plant_field(net, BloodParams())
    t0 = time.perf_counter()
    wa = pf.wall_arrays(net, BloodParams())
    row: dict[str, float] = {"wall_arrays_s": time.perf_counter() - t0, "wall_triangles": float(len(fld.triangles)),
                             "wall_MB": sum(a.nbytes for a in wa.args) / 1e6}
    row.update({k: float(v) for k, v in wa.stats.items() if k in ("build_s", "tube_cells", "model_cells_2", "model_cells_3",
                                                                  "list_cells", "list_mean_len", "exact_cells", "exact_fraction",
                                                                  "exact_MB", "exact_triangles")})
    field = WallField3D.__new__(WallField3D)
    field.head, field.field, field.fine = wa.args[0], wa.args[1], wa.args[2]
    wall = fld.wall
    rng = np.random.default_rng(seed)
    o, h = wa.args[0][:3], wa.args[0][3]
    top = o + h * (np.array([int(v) for v in wa.args[0][4:7]]) - 1)
    got: list[Array] = []
    count = 0
    while count < n:
        q = rng.uniform(o, top, size=(8 * n, 3))
        e = wall.query(q)["sdist"]
        q = q[(e <= pf.BAND_M) & (e >= -pf.OUT_BAND_M)]
        got.append(q)
        count += len(q)
    q = np.ascontiguousarray(np.concatenate(got)[:n])
    r = field_points3d(q, *wa.args)
    e = wall.query(q)
    ang = angle_deg(r[:, 1:4], e["normal"])
    turn = np.zeros(len(q))  # the exact normal's turn within 5 um of each point (6 random directions)
    for _ in range(6):
        step = rng.normal(size=q.shape)
        step *= 5e-6 / np.linalg.norm(step, axis=1)[:, None]
        turn = np.maximum(turn, angle_deg(wall.query(q + step)["normal"], e["normal"]))
    ill = turn > 2.0
    row["points"] = float(len(q))
    row["exact_share_points"] = float(field.exact_mask(q).mean())
    row["list_share_points"] = float(field.list_mask(q).mean())
    row["vs_exact_dist_um"] = float(np.abs(r[:, 0] - e["sdist"]).max() * 1e6)
    row["vs_exact_normal_deg_well_conditioned"] = float(ang[~ill].max())
    row["vs_exact_normal_deg_p99"] = float(np.percentile(ang, 99))
    row["ill_conditioned_points"] = float(ill.sum())
    row["ill_conditioned_points_over_2deg"] = float((ill & (ang > 2.0)).sum())
    row["vs_exact_normal_deg_all"] = float(ang.max())
    far = np.abs(e["sdist"]) > 5e-6
    row["sign_mismatches_vs_exact"] = float(((r[:, 0] > 0) != (e["sdist"] > 0))[far].sum())
    # the fine surface against its straight round branches
    v, t = fld.vertices, fld.triangles
    cen = v[t].mean(axis=1)
    branches = straight_branches(net)
    for label, pts in (("vertices", v), ("centroids", cen)):
        errs = []
        owner = np.array(nearest_branch(net, pts))
        for nm, a, b, rad in branches:
            u = (b - a) / np.linalg.norm(b - a)
            along = (pts - a) @ u
            keep = (owner == nm) & (along > 1.5 * rad) & (along < np.linalg.norm(b - a) - 1.5 * rad)
            if keep.any():
                dist = np.linalg.norm(pts[keep] - a - along[keep, None] * u, axis=1)
                errs.append(dist - rad)
        if errs:
            allerr = np.concatenate(errs)
            row[f"analytic_{label}_n"] = float(len(allerr))
            row[f"analytic_{label}_radius_err_um_max"] = float(np.abs(allerr).max() * 1e6)
            row[f"analytic_{label}_radius_err_um_p99"] = float(np.percentile(np.abs(allerr), 99) * 1e6)
    row.update({f"mesh_{k}": float(v) for k, v in fld.meta.get("wall", {}).items()})
    return row


def main() -> None:
    """Print the validation tables."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--h-mm", type=float, default=0.1, help="grid spacing (mm)")
    ap.add_argument("--mesh-mm", type=float, default=0.1, help="wall triangle size (mm)")
    ap.add_argument("--float64", action="store_true", help="store the samples in float64 (default float32)")
    ap.add_argument("--points", type=int, default=200_000, help="random points per geometry")
    ap.add_argument("--refine", type=int, default=1, help="sub-cells per axis in flagged cells (1: none)")
    ap.add_argument("--shipped", action="store_true", help="the shipped trees' walls, as the 3-D plant builds them")
    ap.add_argument("--tree", action="append", help="with --shipped: this tree only (repeatable)")
    a = ap.parse_args()
    if a.shipped:
        for name in a.tree or ("paper_iiic_artery_3d", "carotid_bifurcation_3d", "synthetic_tree_3d"):
            print(f"== {name} (shipped; standard within 1 mm in the lumen and 0.1 mm outside)")
            for k, val in shipped(name, a.points).items():
                print(f"  {k:36s} {val:.4g}")
        print("standard: distance <= 5 um, normal <= 2 deg")
        return
    res = validate(a.h_mm * 1e-3, a.mesh_mm * 1e-3, np.float64 if a.float64 else np.float32, a.points, refine=a.refine)
    for name, row in res.items():
        print(f"== {name} (grid {a.h_mm} mm, {'float64' if a.float64 else 'float32'}, wall triangles {a.mesh_mm} mm)")
        for k, val in row.items():
            print(f"  {k:30s} {val:.4g}")
    print("standard: distance <= 5 um, normal <= 2 deg within 1 mm of the wall")


if __name__ == "__main__":
    main()
