"""Reference 3-D walls for validation and tests: gmsh/OpenCASCADE solids meshed, and the analytic Y.

A cylinder, a torus section and a Y of three cylinders fused with a ball (:data:`Y_BRANCHES`), each as
(vertices, triangles, caps, CAD vertex normals) for :class:`~vesselbot_ros.geometry.surface_wall.Wall3D`;
:func:`y_solids` is the Y's analytic inside test.  See docs/vessels.md, "The wall geometry".
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.geometry.surface import Array, Cap, IArray

__all__ = ["gmsh_wall", "cylinder_wall", "bent_tube_wall", "Y_BRANCHES", "y_wall", "y_solids"]

def gmsh_wall(build: Callable[[Any], None], h_m: float, unit_m: float = 1e-3) -> tuple[Array, IArray, Array]:
    """The wall of a solid built with gmsh's OpenCASCADE kernel: a surface mesh, planar faces (caps) left out.

    Args:
        build: Called with ``gmsh.model.occ``; builds the solid (in ``unit_m``, e.g. millimetres).
        h_m: Triangle size (m).
        unit_m: The length unit ``build`` works in (m).

    Returns:
        ``(vertices (n, 3) m, triangles (t, 3), normals (n, 3))`` of every non-planar face; normals: the CAD
        surface's unit normal at each vertex (sign as the CAD has it; at a vertex shared by faces, one face's).
    """
    import gmsh  # deferred: heavy, and its wheel needs libGLU & co (tools/bootstrap.sh checks); only meshing needs it

    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("wall3d")
        build(gmsh.model.occ)
        gmsh.model.occ.synchronize()
        h = h_m / unit_m
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        gmsh.model.mesh.generate(2)
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        tris = []
        normals: dict[int, Array] = {}
        for _dim, tag in gmsh.model.getEntities(2):
            if gmsh.model.getType(2, tag) == "Plane":
                continue
            ntags, _xyz, par = gmsh.model.mesh.getNodes(2, tag, includeBoundary=True, returnParametricCoord=True)
            nrm = np.asarray(gmsh.model.getNormal(tag, par), dtype=np.float64).reshape(-1, 3)
            normals.update(zip(np.asarray(ntags, dtype=np.int64).tolist(), nrm))
            types, _et, enodes = gmsh.model.mesh.getElements(2, tag)
            for ty, en in zip(types, enodes):
                if ty == 2:
                    tris.append(np.asarray(en, dtype=np.int64).reshape(-1, 3))
    finally:
        gmsh.finalize()
    tags = np.asarray(node_tags, dtype=np.int64)
    xyz = np.asarray(coords, dtype=np.float64).reshape(-1, 3) * unit_m
    lookup = np.full(tags.max() + 1, -1, dtype=np.int64)
    lookup[tags] = np.arange(len(tags))
    tri = lookup[np.concatenate(tris)]
    used = np.unique(tri)
    remap = np.full(len(tags), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    nv = np.array([normals[int(g)] for g in tags[used]])
    return np.ascontiguousarray(xyz[used]), np.ascontiguousarray(remap[tri]), nv


def cylinder_wall(radius_m: float = 1.5e-3, length_m: float = 8e-3, h_m: float = 0.1e-3
                  ) -> tuple[Array, IArray, list[Cap], Array]:
    """A straight cylinder along +x from the origin: (vertices, triangles, caps, CAD vertex normals)."""
    r, L = radius_m * 1e3, length_m * 1e3

    def build(occ: Any) -> None:
        occ.addCylinder(0, 0, 0, L, 0, 0, r)

    v, t, nv = gmsh_wall(build, h_m)
    caps: list[Cap] = [(np.zeros(3), np.array([-1.0, 0, 0]), radius_m),
                       (np.array([length_m, 0, 0]), np.array([1.0, 0, 0]), radius_m)]
    return v, t, caps, nv


def bent_tube_wall(radius_m: float = 1.5e-3, bend_m: float = 6e-3, angle_rad: float = 0.5 * math.pi,
                   h_m: float = 0.1e-3) -> tuple[Array, IArray, list[Cap], Array]:
    """A torus section: tube radius ``radius_m`` round a centreline circle of radius ``bend_m`` about +z
    through the origin, from azimuth 0 to ``angle_rad``: (vertices, triangles, caps, CAD vertex normals)."""
    r, rb = radius_m * 1e3, bend_m * 1e3

    def build(occ: Any) -> None:
        occ.addTorus(0, 0, 0, rb, r, -1, angle_rad)

    v, t, nv = gmsh_wall(build, h_m)
    caps: list[Cap] = [(np.array([bend_m, 0, 0]), np.array([0, -1.0, 0]), radius_m),
                       (bend_m * np.array([math.cos(angle_rad), math.sin(angle_rad), 0]),
                        np.array([-math.sin(angle_rad), math.cos(angle_rad), 0]), radius_m)]
    return v, t, caps, nv


#: The Y's branches: (start (3,) m, unit direction, length m, radius m): a parent along +x ending at the
#: origin and two daughters leaving it at +-35 deg in the xy plane.
Y_BRANCHES = (
    (np.array([-6e-3, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), 6e-3, 1.5e-3),
    (np.zeros(3), np.array([math.cos(math.radians(35)), math.sin(math.radians(35)), 0.0]), 6e-3, 1.2e-3),
    (np.zeros(3), np.array([math.cos(math.radians(35)), -math.sin(math.radians(35)), 0.0]), 6e-3, 1.2e-3),
)


def y_wall(h_m: float = 0.1e-3) -> tuple[Array, IArray, list[Cap], Array]:
    """A Y: :data:`Y_BRANCHES`' cylinders and a ball of the parent's radius at the node, fused:
    (vertices, triangles, caps, CAD vertex normals)."""

    def build(occ: Any) -> None:
        vols = []
        for s, u, L, r in Y_BRANCHES:
            vols.append((3, occ.addCylinder(*(s * 1e3), *(u * L * 1e3), r * 1e3)))
        vols.append((3, occ.addSphere(0, 0, 0, Y_BRANCHES[0][3] * 1e3)))
        occ.fuse(vols[:1], vols[1:])

    v, t, nv = gmsh_wall(build, h_m)
    caps: list[Cap] = [(Y_BRANCHES[0][0], -Y_BRANCHES[0][1], Y_BRANCHES[0][3])]
    caps += [(s + L * u, u, r) for s, u, L, r in Y_BRANCHES[1:]]
    return v, t, caps, nv


def y_solids(q: Array, cap_margin_m: float = 5e-5) -> tuple[npt.NDArray[np.bool_], Array, npt.NDArray[np.bool_]]:
    """The analytic Y of :func:`y_wall` at points ``q`` (n, 3) (m): ``(inside, near, beyond)``: inside the union of
    :data:`Y_BRANCHES`' cylinders and the node's ball, the least |signed distance| to any of those solids (m), and
    beyond a cap by more than ``-cap_margin_m`` along its branch (where the meshed lumen continues as a tube and the
    union ends)."""
    inside = np.linalg.norm(q, axis=1) < Y_BRANCHES[0][3]
    near = np.abs(np.linalg.norm(q, axis=1) - Y_BRANCHES[0][3])
    beyond = np.zeros(len(q), dtype=bool)
    for s, u, length, r in Y_BRANCHES:
        rel = q - s
        t = (rel[:, 0] * u[0] + rel[:, 1] * u[1]) + rel[:, 2] * u[2]
        rho = np.linalg.norm(q - s - t[:, None] * u, axis=1)
        dx, dy = rho - r, np.abs(t - 0.5 * length) - 0.5 * length
        sdf = np.minimum(np.maximum(dx, dy), 0.0) + np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0))
        inside |= sdf < 0
        near = np.minimum(near, np.abs(sdf))
        beyond |= (t > length - cap_margin_m) if s[0] >= 0 else (t < cap_margin_m)
    return inside, near, beyond
