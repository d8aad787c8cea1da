#!/usr/bin/env python3
"""Write the synthetic 3-D tree: a VMTK centreline file and the network imported from it.

A deterministic tree of four generations (the inlet branch and three levels of bifurcations, 8 outlets)
obeying Murray's law, written as ``vmtkcenterlines`` writes a vessel -- one polyline per inlet-to-outlet
path, in millimetres, overlapping along the branches the paths share, with the radius in the point array
``MaximumInscribedSphereRadius`` -- to ``config/vessels/sources/synthetic_tree_3d.vtp``; then imported with
:func:`vesselbot_ros.vessels.tree_io.import_vmtk_centerlines` (as ``vesselbot vessels import`` does) and
written to ``config/vessels/synthetic_tree_3d.yaml``.

The rules (all ours):
* each bifurcation splits its parent's flow 0.6 / 0.4, so by Murray's law (flow ~ r^3) the daughters'
  radii are r (0.6)^(1/3) and r (0.4)^(1/3) (r_a^3 + r_b^3 = r^3); the inlet radius is 1.5 mm (Table III's
  D = 3 mm), the smallest outlet 1.5 mm x 0.4 = 0.6 mm;
* each daughter leaves at Murray's minimum-work angle to its parent's axis,
  cos theta_a = (r^4 + r_a^4 - r_b^4) / (2 r^2 r_a^2) (Murray 1926; 31.6 and 43.4 deg for 0.6 / 0.4),
  the two on either side of the parent's axis in the bifurcation plane;
* the bifurcation plane turns 90 deg about the parent's axis from one generation to the next (the
  alternation of real arterial trees), so the tree is three-dimensional;
* a branch of radius r is 6 r long and bends by 12 deg back towards its parent's axis along its length
  (a quadratic Bezier curve), sampled every 0.25 mm;
* the inlet branch starts at the origin along +x.

Usage: .venv/bin/python tools/make_synthetic_tree_3d.py   (deterministic: rerunning it changes nothing)
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import numpy.typing as npt

from vesselbot_ros.vessels.tree_io import import_vmtk_centerlines, write_network_yaml, write_vmtk_centerlines

sys.path.insert(0, str(Path(__file__).resolve().parent))
from small_artery_flow_presets import FLOW_PRESETS_YAML

ROOT = Path(__file__).resolve().parents[1]
VTP = ROOT / "config" / "vessels" / "sources" / "synthetic_tree_3d.vtp"
YAML = ROOT / "config" / "vessels" / "synthetic_tree_3d.yaml"
NAME = "synthetic_tree_3d"

R0_MM = 1.5
SPLIT = (0.6, 0.4)  # flow shares of the two daughters
GENERATIONS = 4  # the inlet branch and three levels of bifurcations
LENGTH_PER_RADIUS = 6.0
BEND_DEG = 12.0
SPACING_MM = 0.25


def _dot(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> float:
    """``a . b`` of two 3-vectors summed left to right: ``a @ b`` is a BLAS ``ddot``, whose sum order (and fused
    multiply-adds) depend on the CPU's OpenBLAS kernel, and the tree's bytes must not."""
    return float(a[0] * b[0] + a[1] * b[1] + a[2] * b[2])


def _norm(a: npt.NDArray[np.float64]) -> float:
    """``|a|`` by :func:`_dot` (``np.linalg.norm`` of a vector is a BLAS ``ddot`` too)."""
    return math.sqrt(_dot(a, a))


def _rotate(v: npt.NDArray[np.float64], axis: npt.NDArray[np.float64], angle: float) -> npt.NDArray[np.float64]:
    """``v`` turned by ``angle`` (rad) about the unit vector ``axis`` (Rodrigues)."""
    return v * math.cos(angle) + np.cross(axis, v) * math.sin(angle) + axis * _dot(axis, v) * (1.0 - math.cos(angle))


def _branch(start: npt.NDArray[np.float64], heading: npt.NDArray[np.float64], toward: npt.NDArray[np.float64],
            length: float) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Samples (n, 3) of a branch from ``start`` along ``heading`` bending by BEND_DEG towards ``toward``; end tangent."""
    side = toward - _dot(toward, heading) * heading
    if _norm(side) < 1e-12:  # along the parent's axis already: no bend
        end_dir = heading
    else:
        axis = np.cross(heading, side / _norm(side))
        end_dir = _rotate(heading, axis / _norm(axis), math.radians(BEND_DEG))
    p1 = start + 0.5 * length * heading
    p2 = p1 + 0.5 * length * end_dir
    n = int(math.ceil(length / SPACING_MM)) + 1
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = (1 - t) ** 2 * start + 2 * (1 - t) * t * p1 + t ** 2 * p2
    return pts, end_dir


def tree_paths() -> list[tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
    """The inlet-to-outlet paths (points (n, 3) mm, radius (n,) mm), depth first, the larger daughter first."""
    paths = []

    def grow(start: npt.NDArray[np.float64], heading: npt.NDArray[np.float64], normal: npt.NDArray[np.float64],
             r: float, gen: int, prefix: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None,
             parent_axis: npt.NDArray[np.float64]) -> None:
        pts, end_dir = _branch(start, heading, parent_axis, LENGTH_PER_RADIUS * r)
        rad = np.full(len(pts), r)
        if prefix is not None:  # the node's point is the parent's last one
            pts, rad = np.vstack([prefix[0], pts[1:]]), np.concatenate([prefix[1], rad[1:]])
        if gen + 1 == GENERATIONS:
            paths.append((pts, rad))
            return
        ra, rb = (r * s ** (1.0 / 3.0) for s in SPLIT)
        ta = math.acos((r ** 4 + ra ** 4 - rb ** 4) / (2.0 * r * r * ra * ra))
        tb = math.acos((r ** 4 + rb ** 4 - ra ** 4) / (2.0 * r * r * rb * rb))
        # the bifurcation plane holds end_dir and the binormal; it turns 90 deg about the axis each generation
        plane = _rotate(normal, end_dir, math.pi / 2.0)
        plane = plane - _dot(plane, end_dir) * end_dir
        plane /= _norm(plane)
        for rr, th, sgn in ((ra, ta, 1.0), (rb, tb, -1.0)):
            d = _rotate(end_dir, plane, sgn * th)
            grow(pts[-1], d, plane, rr, gen + 1, (pts, rad), end_dir)

    x = np.array([1.0, 0.0, 0.0])
    grow(np.zeros(3), x, np.array([0.0, 0.0, 1.0]), R0_MM, 0, None, x)
    return paths


def main() -> int:
    VTP.parent.mkdir(parents=True, exist_ok=True)
    write_vmtk_centerlines(tree_paths(), VTP)
    net = import_vmtk_centerlines(VTP, name=NAME, length_unit_m=1.0e-3)
    # the 3-D solve's mesh: 0.3 mm in the lumen, 24 elements round every wall (32 round the 0.6 mm twigs would
    # not fit the solve's budget)
    net = dataclasses.replace(net, cfd=dataclasses.replace(net.cfd, mesh_size_3d_m=3.0e-4, wall_elements_per_circle_3d=24))
    header = (f"A synthetic 3-D tree of {GENERATIONS} generations ({len(net.outlets)} outlets) obeying Murray's law,\n"
              f"imported from the VMTK centreline file sources/{VTP.name} (generated by tools/make_synthetic_tree_3d.py:\n"
              "flow split 0.6 / 0.4 at every node, radii r (0.6)^(1/3) and r (0.4)^(1/3), Murray's minimum-work angles,\n"
              "bifurcation planes turning 90 deg per generation, inlet r = 1.5 mm, smallest outlet r = 0.6 mm).\n"
              "Do not edit: regenerate with .venv/bin/python tools/make_synthetic_tree_3d.py.  Format: docs/vessels.md.")
    write_network_yaml(net, YAML, header=header, footer=FLOW_PRESETS_YAML)
    print(f"wrote {VTP.relative_to(ROOT)} ({len(tree_paths())} paths) and {YAML.relative_to(ROOT)} "
          f"({len(net.branches)} branches, {len(net.outlets)} outlets)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
