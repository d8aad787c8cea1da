"""Vessel trees from and to files: VMTK centreline files in, our network YAML out.

VMTK (``vmtkcenterlines``) writes a vessel's centrelines as VTK PolyData
(``.vtp``): polylines with the radius of the maximum inscribed sphere at every
point (point array ``MaximumInscribedSphereRadius``), in the units of the image
(millimetres, usually).  Two forms are read:

* the raw form of ``vmtkcenterlines``: one polyline per inlet-to-outlet path,
  all starting at the inlet and overlapping along the segments they share.
  The paths are split into branches where they part: two paths part where one
  leaves the tube of ``split_tolerance`` (0.5) times the other's radius around
  it, and the bifurcation node is put back at the last point before that where
  they were still within a tenth of it (on a shared segment VMTK's paths
  coincide, so the node is where they start to diverge).  Paths that stay
  together beyond a node form one branch; a node where three groups part is a
  trifurcation.  The inlet is the common end of the paths (their first points,
  or their last ones: the lines are then reversed).
* the branch-split form of ``vmtkbranchextractor``: the same lines cut into
  tracts with the cell arrays ``CenterlineIds``, ``TractIds``, ``GroupIds``
  and ``Blanking`` (1 on the tracts through a bifurcation).  Each unblanked
  group is a branch (the tract of its lowest centreline id); a daughter starts
  at its parent's end and runs through its centreline's blanked tract to its
  own tract.

Junctions (both forms): near a bifurcation a maximum inscribed sphere touches the walls of the
parent and of both daughters, so its radius is the junction's, not a branch's lumen radius (on the
shared segment up to the node it is the parent's; just past the node it is still about the
parent's, not the daughter's).  VMTK's own ``vmtkbranchextractor`` blanks that region, and
centreline-based tools take a branch's radius from outside the junction's sphere; so does the
importer: a daughter's points closer to its node than ``junction_factor`` (1.0) times the radius
there (the parent's end radius: the junction's maximum inscribed sphere) take the radius of the
daughter's first point at or beyond that distance (its last point's if it has none); its
centreline points are kept.  ``junction_factor`` 0 keeps the file's radii.

Coordinates are scaled by ``length_unit_m`` (1e-3: the file is in mm) and
rounded to 1 nm, and consecutive points closer than that are dropped, so a
written network reloads to the same numbers.  The file's x, y, z are the
network's (gravity along -z).

A file that does not parse, holds no polylines, or lacks the radius array
raises :class:`~vesselbot_ros.config.ConfigError` in one line naming the file and
the cause; so does a tree that fails the network's validation
(:class:`~vesselbot_ros.vessels.network.VesselNetworkParams`).

Writing: :func:`write_network_yaml` writes a network as our YAML (one flow-style
list per coordinate), :func:`write_vmtk_centerlines` a raw-form ``.vtp`` (the
synthetic tree's generator uses it).  ``vtk`` is imported only when a file is
read or written.
"""

from __future__ import annotations

import dataclasses
import errno
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from vesselbot_ros.atomic_io import atomic_path, write_text
from vesselbot_ros.config import ConfigError, load_dataclass, to_mapping
from vesselbot_ros.resources import require_fits
from vesselbot_ros.vessels.network import MAX_LENGTH_M, MAX_RADIUS_M, MIN_RADIUS_M, CfdParams, VesselNetworkParams

__all__ = [
    "RADIUS_ARRAY",
    "CentrelineFile",
    "import_vmtk_centerlines",
    "network_mapping_from_paths",
    "read_vmtk_centerlines",
    "write_network_yaml",
    "write_vmtk_centerlines",
]

#: VMTK's point array of the maximum inscribed sphere's radius.
RADIUS_ARRAY = "MaximumInscribedSphereRadius"
#: Cell arrays of ``vmtkbranchextractor``'s branch-split form.
SPLIT_ARRAYS = ("CenterlineIds", "TractIds", "GroupIds", "Blanking")
#: Coordinates are rounded to this many decimals of a metre (1 nm).
DECIMALS = 9
#: What reading a centreline file holds per byte of it (VTK's arrays, their numpy copies, the paths; rounded up).
READ_BYTES_PER_FILE_BYTE = 16

Path3 = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]  # (points (n, 3), radius (n,))


@dataclasses.dataclass
class CentrelineFile:
    """What :func:`read_vmtk_centerlines` found in a file (file units).

    Attributes:
        lines: One (points (n, 3), radius (n,)) per polyline cell, in cell order.
        cell_arrays: The cell arrays of :data:`SPLIT_ARRAYS` present, by name, one int per cell.
    """

    lines: list[Path3]
    cell_arrays: dict[str, npt.NDArray[np.int64]]

    @property
    def branch_split(self) -> bool:
        """True if the file carries ``vmtkbranchextractor``'s group arrays."""
        return all(k in self.cell_arrays for k in SPLIT_ARRAYS)


def _fail(path: str | os.PathLike[str], cause: str) -> ConfigError:
    return ConfigError(f"VMTK centreline file {str(path)!r}: {cause}")


def read_vmtk_centerlines(path: str | os.PathLike[str], radius_array: str = RADIUS_ARRAY) -> CentrelineFile:
    """Read the polylines and radii of a VTK PolyData file (``.vtp`` XML or legacy ``.vtk``).

    Args:
        path: The file.
        radius_array: Name of the point array of radii.

    Returns:
        The polylines (file units) and the branch-split cell arrays present.

    Raises:
        ConfigError: one line naming the file and the cause (missing, unreadable, not PolyData,
            no polylines, no radius array, a radius <= 0 or not finite).
    """
    p = Path(path)
    if not p.is_file():
        raise _fail(path, "no such file")
    size = p.stat().st_size  # VTK holds the file, its arrays, and numpy copies of them: bounded before it reads
    require_fits(f"VMTK centreline file {str(path)!r}", f"{size} bytes", READ_BYTES_PER_FILE_BYTE * size,
                 what="reading it", hint="thin its centrelines (vmtkcenterlineresampling)")
    # deferred: vtk is large (~0.3 s, 100 MB) and only the importer needs it
    import vtkmodules.vtkIOLegacy as vtk_legacy
    import vtkmodules.vtkIOXML as vtk_xml  # deferred: as above
    from vtkmodules.util.numpy_support import vtk_to_numpy  # deferred: as above
    from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow, vtkStringOutputWindow  # deferred: as above

    # VTK reports errors on its output window (and its logger on stderr): collect them, print nothing
    window = vtkStringOutputWindow()
    previous = vtkOutputWindow.GetInstance()
    verbosity = vtkLogger.GetCurrentVerbosityCutoff()
    vtkOutputWindow.SetInstance(window)
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    try:
        if p.suffix.lower() == ".vtk":
            reader: Any = vtk_legacy.vtkPolyDataReader()
        else:
            reader = vtk_xml.vtkXMLPolyDataReader()
            if not reader.CanReadFile(str(p)):
                raise _fail(path, "not a VTK XML PolyData file (.vtp)")
        reader.SetFileName(str(p))
        reader.Update()
        if p.suffix.lower() == ".vtk" and not reader.IsFilePolyData():
            raise _fail(path, "not a legacy VTK PolyData file")
    finally:
        vtkOutputWindow.SetInstance(previous)
        vtkLogger.SetStderrVerbosity(verbosity)
    errors = [m.group(1).strip() for m in re.finditer(r"^vtk\w+ \(0x[0-9a-f]+\): (.*)$", window.GetOutput(), re.M)]
    poly = reader.GetOutput()
    if "ERROR" in window.GetOutput() or poly is None:
        raise _fail(path, "VTK could not parse it" + (f": {errors[0]}" if errors else ""))
    if poly.GetNumberOfLines() == 0:
        raise _fail(path, f"holds no polylines ({poly.GetNumberOfPoints()} points, {poly.GetNumberOfPolys()} polygons): "
                          "not a centreline file")
    pd = poly.GetPointData()
    arr = pd.GetArray(radius_array)
    if arr is None:
        names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
        raise _fail(path, f"has no point array {radius_array!r} of radii; point arrays: {names}")
    pts = vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64).reshape(-1, 3)
    rad = vtk_to_numpy(arr).astype(np.float64).reshape(len(pts), -1)[:, 0]
    lines: list[Path3] = []
    cells = poly.GetLines()
    cells.InitTraversal()
    # deferred: as above
    from vtkmodules.vtkCommonCore import vtkIdList

    ids = vtkIdList()
    offset = poly.GetNumberOfVerts()  # cell ids of lines follow the vertices'
    line_cells: list[int] = []
    k = 0
    while cells.GetNextCell(ids):
        idx = np.array([ids.GetId(i) for i in range(ids.GetNumberOfIds())], dtype=np.int64)
        if len(idx) >= 2:
            r = rad[idx]
            bad = ~(np.isfinite(r) & (r > 0.0))
            if bad.any():
                j = int(np.argmax(bad))
                raise _fail(path, f"{radius_array}[{int(idx[j])}] (line {k}, point {j}) must be > 0, got {float(r[j])!r}")
            if not np.isfinite(pts[idx]).all():
                raise _fail(path, f"line {k} has a point that is not finite")
            lines.append((pts[idx], r))
            line_cells.append(offset + k)
        k += 1
    if not lines:
        raise _fail(path, "holds no polyline of 2 points or more")
    cd = poly.GetCellData()
    cell_arrays = {}
    for name in SPLIT_ARRAYS:
        a = cd.GetArray(name)
        if a is not None:
            cell_arrays[name] = vtk_to_numpy(a).astype(np.int64).reshape(-1)[line_cells]
    return CentrelineFile(lines, cell_arrays)


def _clean(points: npt.NDArray[np.float64], radius: npt.NDArray[np.float64], scale: float) -> Path3:
    """Scale to metres, round to 1 nm, drop points within 1 nm of the previous one."""
    q = np.round(points * scale, DECIMALS)
    r = np.round(radius * scale, DECIMALS)
    keep = [0]
    for i in range(1, len(q)):
        if np.abs(q[i] - q[keep[-1]]).max() > 0.0:
            keep.append(i)
    return q[keep], r[keep]


def _polyline_distance(q: npt.NDArray[np.float64], pts: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(m,) distance of the points ``q`` (m, 3) to the polyline ``pts`` (n, 3)."""
    if len(pts) == 1:
        return np.linalg.norm(q - pts[0], axis=1)
    a = pts[:-1]
    d = pts[1:] - a
    L2 = np.maximum((d * d).sum(axis=1), 1e-300)
    out = np.full(len(q), np.inf)
    for lo in range(0, len(q), 256):  # bounded memory: 256 x n segments at a time
        qq = q[lo:lo + 256]
        t = np.clip(((qq[:, None, :] - a[None]) * d[None]).sum(axis=2) / L2[None], 0.0, 1.0)
        f = a[None] + t[..., None] * d[None]
        out[lo:lo + 256] = np.sqrt(((qq[:, None, :] - f) ** 2).sum(axis=2)).min(axis=1)
    return out


def _parting(a: Path3, sa: int, b: Path3, sb: int, tol: float) -> int | None:
    """Index along ``a`` (>= ``sa``) of the node where ``b`` (from ``sb``) parts from it; None if it never does.

    They part at the first point of ``a`` farther than ``tol`` r_a from ``b``; the node is the last
    point before it within ``tol / 10`` r_a (or ``sa``).
    """
    pa, ra = a
    d = _polyline_distance(pa[sa:], b[0][sb:])
    far = np.nonzero(d > tol * ra[sa:])[0]
    if len(far) == 0:
        return None
    near = np.nonzero(d[:far[0]] <= 0.1 * tol * ra[sa:sa + far[0]])[0]
    return sa + (int(near[-1]) if len(near) else 0)


def _junction_radii(pts: npt.NDArray[np.float64], rad: npt.NDArray[np.float64], node_radius: float,
                    factor: float) -> npt.NDArray[np.float64]:
    """A daughter's radii (its first point the node) with those within the junction's sphere replaced.

    Points closer to the node than ``factor * node_radius`` take the radius of the first point at or
    beyond that distance (the last point's if none is).
    """
    if factor <= 0.0 or len(pts) < 2:
        return rad
    dist = np.linalg.norm(pts - pts[0], axis=1)
    beyond = np.nonzero(dist >= factor * node_radius)[0]
    j = int(beyond[0]) if len(beyond) else len(pts) - 1
    out = rad.copy()
    out[:j] = rad[j]
    return out


def _check_junction_factor(junction_factor: float) -> None:
    if not (math.isfinite(junction_factor) and 0.0 <= junction_factor <= 10.0):
        raise ConfigError(f"junction_factor must be in [0, 10], got {junction_factor!r}")


def _nearest_index(path: Path3, point: npt.NDArray[np.float64], start: int) -> int:
    return start + int(np.argmin(np.linalg.norm(path[0][start:] - point, axis=1)))


def network_mapping_from_paths(paths: Sequence[Path3], name: str, split_tolerance: float = 0.5,
                               source: str = "paths", junction_factor: float = 1.0) -> dict[str, Any]:
    """The network mapping (``VesselNetworkParams``' keys) of inlet-to-outlet paths sharing their inlet.

    Args:
        paths: (points (n, 3) m, radius (n,) m) per path, each from the inlet (its first point).
        name: The network's name.
        split_tolerance: Two paths part where one leaves the tube of this fraction of the other's radius.
        source: What the paths came from, for error messages.
        junction_factor: A daughter's points closer to its node than this times the parent's end
            radius take the daughter's radius just beyond (module docstring); 0 keeps the paths' radii.

    Returns:
        ``{"name", "branches": [...]}``: branch names spell the route from the root ``b0``
        (``b0_1_0``: the root's second daughter's first daughter); a branch's points are its
        representative path's (the longest of the paths through it) between its nodes, its radii
        theirs but within the junction at its start.

    Raises:
        ConfigError: if a path ends on another one (not an outlet).
    """
    if not 0.0 < split_tolerance <= 10.0:
        raise ConfigError(f"split_tolerance must be in (0, 10], got {split_tolerance!r}")
    _check_junction_factor(junction_factor)
    branches: list[dict[str, Any]] = []

    def arc_to_end(k: int, start: int) -> float:
        return float(np.linalg.norm(np.diff(paths[k][0][start:], axis=0), axis=1).sum())

    def emit(bname: str, parent: str, node: npt.NDArray[np.float64], pts: npt.NDArray[np.float64],
             rad: npt.NDArray[np.float64], node_r: float) -> float:
        """Append the branch; its end radius."""
        pts = np.vstack([node, pts[1:]])
        keep = np.concatenate([[True], np.abs(pts[1:] - node).max(axis=1) > 0.0])
        pts, rad = pts[keep], rad[keep]
        if parent:
            rad = _junction_radii(pts, rad, node_r, junction_factor)
        branches.append({"name": bname, "parent": parent, "x_m": pts[:, 0].tolist(), "y_m": pts[:, 1].tolist(),
                         "z_m": pts[:, 2].tolist(), "radius_m": rad.tolist()})
        return float(rad[-1])

    def grow(group: list[int], starts: dict[int, int], node: npt.NDArray[np.float64], node_r: float, parent: str,
             bname: str) -> None:
        """Branch ``bname`` shared by ``group`` from ``node``, then its daughters."""
        group = sorted(group, key=lambda k: -arc_to_end(k, starts[k]))
        a = group[0]
        sa = starts[a]
        pa, ra = paths[a]
        parts = {}
        for b in group[1:]:
            m = _parting(paths[a], sa, paths[b], starts[b], split_tolerance)
            if m is None:
                raise ConfigError(f"{source}: path {b} ends on path {a} (at {pa[-1].tolist()} m): every path must "
                                  "run from the inlet to its own outlet")
            parts[b] = m
        end = min(parts.values()) if parts else len(pa) - 1
        if end <= sa and parts:
            raise ConfigError(f"{source}: paths {a} and {min(parts, key=parts.__getitem__)} part at "
                              f"{pa[sa].tolist()} m, where a branch starts: two bifurcations closer than "
                              "the split tolerance")
        if end - sa < 1:
            end = min(sa + 1, len(pa) - 1)
        end_r = emit(bname, parent, node, pa[sa:end + 1], ra[sa:end + 1], node_r)
        if not parts:
            return
        nxt = pa[end]
        stay = [a] + [b for b in group[1:] if parts[b] > end]
        left = [b for b in group[1:] if parts[b] == end]
        sub_starts = {k: (end if k == a else _nearest_index(paths[k], nxt, starts[k])) for k in group}
        clusters = [stay]
        while left:  # the paths that part here, in groups that stay together beyond the node
            c0 = left[0]
            together = [c0] + [c for c in left[1:] if _shared(c0, c, sub_starts)]
            clusters.append(together)
            left = [c for c in left if c not in together]
        for i, cl in enumerate(clusters):
            grow(cl, sub_starts, nxt, end_r, bname, f"{bname}_{i}")

    def _shared(c0: int, c: int, starts: dict[int, int]) -> bool:
        """True if paths ``c0`` and ``c`` run together beyond their starts (one within the other's tube)."""
        m = _parting(paths[c0], starts[c0], paths[c], starts[c], split_tolerance)
        return m is None or m > starts[c0]

    root = np.asarray(paths[0][0][0])
    grow(list(range(len(paths))), dict.fromkeys(range(len(paths)), 0), root, float(paths[0][1][0]), "", "b0")
    return {"name": name, "branches": branches}


def _orient(lines: list[Path3]) -> list[Path3]:
    """The paths from their common end (the inlet): reversed if their last points are the common ones."""
    if len(lines) < 2:
        return lines
    first = np.array([p[0] for p, _r in lines])
    last = np.array([p[-1] for p, _r in lines])
    spread_first = float(np.linalg.norm(first - first[0], axis=1).max())
    spread_last = float(np.linalg.norm(last - last[0], axis=1).max())
    if spread_last < spread_first:
        return [(p[::-1].copy(), r[::-1].copy()) for p, r in lines]
    return lines


def _split_form_mapping(f: CentrelineFile, scale: float, name: str, source: str,
                        junction_factor: float = 1.0) -> dict[str, Any]:
    """Network mapping of ``vmtkbranchextractor``'s branch-split form."""
    a = f.cell_arrays
    cl, tract, group, blank = a["CenterlineIds"], a["TractIds"], a["GroupIds"], a["Blanking"]
    cells_of: dict[int, list[int]] = {}  # centreline -> its cells in tract order
    for c in np.unique(cl):
        idx = np.nonzero(cl == c)[0]
        cells_of[int(c)] = [int(i) for i in idx[np.argsort(tract[idx], kind="stable")]]
    rep: dict[int, int] = {}  # group -> cell of its lowest centreline id
    parent_of: dict[int, int | None] = {}
    via: dict[int, int | None] = {}  # group -> the blanked cell leading into it on its representative centreline
    for c in sorted(cells_of):
        prev_group: int | None = None
        prev_blank: int | None = None
        for cell in cells_of[c]:
            g = int(group[cell])
            if blank[cell]:
                prev_blank = cell
                continue
            if g not in rep:
                rep[g] = cell
                parent_of[g] = prev_group
                via[g] = prev_blank
            elif parent_of[g] != prev_group:
                raise ConfigError(f"{source}: group {g} follows group {parent_of[g]} on one centreline and "
                                  f"{prev_group} on centreline {c}: not a tree")
            prev_group, prev_blank = g, None
    roots = [g for g, p in parent_of.items() if p is None]
    if len(roots) != 1:
        raise ConfigError(f"{source}: the branch-split centrelines must start in one group (the inlet's), got groups {roots}")
    names = {g: f"g{g}" for g in rep}
    branches = []
    ends: dict[int, npt.NDArray[np.float64]] = {}
    end_radius: dict[int, float] = {}
    order = [roots[0]]
    for g in order:  # breadth first: a parent's end is known before its daughters
        order.extend(sorted(d for d, p in parent_of.items() if p == g))
    for g in order:
        pts, rad = f.lines[rep[g]]
        v = via[g]
        if v is not None:  # through the bifurcation along this centreline
            bp, br = f.lines[v]
            pts, rad = np.vstack([bp, pts]), np.concatenate([br, rad])
        pts, rad = _clean(pts, rad, scale)
        p = parent_of[g]
        if p is not None:  # start at the parent's end: on it if the tract starts within half a radius, else from it
            gap = pts[0] - ends[p]  # its length by elementwise sums: np.linalg.norm of a vector is a BLAS ddot
            if math.sqrt(gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]) < 0.5 * rad[0]:
                pts = np.vstack([ends[p], pts[1:]])
            else:
                pts, rad = np.vstack([ends[p], pts]), np.concatenate([rad[:1], rad])
            keep = np.concatenate([[True], np.abs(pts[1:] - pts[0]).max(axis=1) > 0.0])
            pts, rad = pts[keep], rad[keep]
            rad = _junction_radii(pts, rad, end_radius[p], junction_factor)
        ends[g] = pts[-1]
        end_radius[g] = float(rad[-1])
        branches.append({"name": names[g], "parent": names[p] if p is not None else "",
                         "x_m": pts[:, 0].tolist(), "y_m": pts[:, 1].tolist(), "z_m": pts[:, 2].tolist(),
                         "radius_m": rad.tolist()})
    return {"name": name, "branches": branches}


def _check_units(f: CentrelineFile, length_unit_m: float, src: str) -> None:
    """Refuse, before any work, a file whose radii or extent are not a blood vessel's in ``length_unit_m``.

    A vessel's radius lies in [:data:`~vesselbot_ros.vessels.network.MIN_RADIUS_M`,
    :data:`~vesselbot_ros.vessels.network.MAX_RADIUS_M`] and a tree spans at most
    :data:`~vesselbot_ros.vessels.network.MAX_LENGTH_M` (a file in mm read with ``--unit-m 1`` is 1000 times
    too large: its tubes would be metres wide and its samples billions).
    """
    rad = np.concatenate([r for _p, r in f.lines]) * length_unit_m
    pts = np.concatenate([p for p, _r in f.lines]) * length_unit_m
    extent = float((pts.max(axis=0) - pts.min(axis=0)).max())
    lo, hi = float(rad.min()), float(rad.max())
    unit = f"length_unit_m (--unit-m) = {length_unit_m!r}"
    if lo < MIN_RADIUS_M or hi > MAX_RADIUS_M:
        raise ConfigError(f"{src}: with {unit} its radii are {lo:.3g} to {hi:.3g} m, outside a blood vessel's "
                          f"{MIN_RADIUS_M:g} to {MAX_RADIUS_M:g} m: is the unit right (VMTK works in mm: 1e-3)?")
    if extent > MAX_LENGTH_M:
        raise ConfigError(f"{src}: with {unit} it spans {extent:.3g} m, more than a vessel tree's "
                          f"{MAX_LENGTH_M:g} m: is the unit right (VMTK works in mm: 1e-3)?")


def _network_name(path: Path, name: str | None) -> str:
    if name:
        return name
    return re.sub(r"[^A-Za-z0-9_.-]", "_", path.stem) or "network"


def import_vmtk_centerlines(path: str | os.PathLike[str], *, name: str | None = None, length_unit_m: float = 1.0e-3,
                            split_tolerance: float = 0.5, junction_factor: float = 1.0,
                            radius_array: str = RADIUS_ARRAY,
                            smoothing: str = "spline", sample_spacing_m: float = 2.0e-5,
                            cfd: CfdParams | None = None) -> VesselNetworkParams:
    """A validated network from a VMTK centreline file (raw or branch-split form: module docstring).

    Args:
        path: The ``.vtp`` (or legacy ``.vtk``) file.
        name: The network's name (default: the file's stem).
        length_unit_m: The file's length unit in metres (VMTK works in mm: 1e-3).
        split_tolerance: Raw form: two paths part where one leaves the tube of this fraction of the
            other's radius.
        junction_factor: A daughter's points closer to its node than this times the parent's end
            radius (the junction's maximum inscribed sphere) take the daughter's radius just beyond
            it; 0 keeps the file's radii (module docstring).
        radius_array: Point array of radii.
        smoothing: The network's ``smoothing``.
        sample_spacing_m: The network's ``sample_spacing_m``.
        cfd: The network's CFD settings (default: the defaults).

    Returns:
        The network (:class:`VesselNetworkParams`; validated: a tree without overlapping tubes).

    Raises:
        ConfigError: one line naming the file and the cause.
    """
    if not (math.isfinite(length_unit_m) and length_unit_m > 0.0):
        raise ConfigError(f"length_unit_m must be > 0, got {length_unit_m!r}")
    _check_junction_factor(junction_factor)
    p = Path(path)
    f = read_vmtk_centerlines(p, radius_array)
    nm = _network_name(p, name)
    src = f"VMTK centreline file {str(path)!r}"
    _check_units(f, length_unit_m, src)
    try:
        if f.branch_split:
            mapping = _split_form_mapping(f, length_unit_m, nm, src, junction_factor)
        else:
            lines = _orient([_clean(pts, r, length_unit_m) for pts, r in f.lines])
            mapping = network_mapping_from_paths(lines, nm, split_tolerance, src, junction_factor)
        for br in mapping["branches"]:
            if not any(br["y_m"]):  # a branch in the plane y = 0 is written without y_m: reloads equal
                del br["y_m"]
        mapping.update(smoothing=smoothing, sample_spacing_m=sample_spacing_m)
        if cfd is not None:
            mapping["cfd"] = to_mapping(cfd)
        return load_dataclass(VesselNetworkParams, mapping, "")
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(src) else f"{src}: {msg}") from None


class _FlowList(list[Any]):
    """A list YAML writes in flow style (``[a, b, c]``)."""


def _flow_list(dumper: yaml.SafeDumper, data: _FlowList) -> yaml.Node:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True)


class _Dumper(yaml.SafeDumper):
    pass


_Dumper.add_representer(_FlowList, _flow_list)


def write_network_yaml(net: VesselNetworkParams, path: str | os.PathLike[str], header: str = "", footer: str = "") -> None:
    """Write ``net`` as a network YAML file (atomically: a temporary file renamed over ``path``).

    Args:
        net: The network.
        path: The file to write.
        header: Comment lines written first (``# `` is prefixed to each line).
        footer: YAML text written last, as given (a commented block of more keys, such as ``flow_presets``).
    """
    m = to_mapping(net)
    for b in m["branches"]:
        for k in ("x_m", "y_m", "z_m", "radius_m"):
            if k in b:
                b[k] = _FlowList(b[k])
    if net.cfd == CfdParams():
        del m["cfd"]
    order = ["name", "smoothing", "sample_spacing_m", "branches", "cfd"]
    m = {k: m[k] for k in order if k in m}
    m["branches"] = [{k: b[k] for k in ("name", "parent", "x_m", "y_m", "z_m", "radius_m") if k in b}
                     for b in m["branches"]]
    text = "".join(f"# {line}".rstrip() + "\n" for line in header.splitlines())
    text += yaml.dump(m, Dumper=_Dumper, sort_keys=False, width=120) + footer
    write_text(path, text)  # whole or not at all (a full disk: one line naming the file, no partial file)


def write_vmtk_centerlines(paths: Sequence[Path3], path: str | os.PathLike[str],
                           cell_arrays: dict[str, Sequence[int]] | None = None) -> None:
    """Write polylines with radii as a VMTK-style centreline ``.vtp`` (binary XML, uncompressed).

    Args:
        paths: (points (n, 3), radius (n,)) per polyline, in the file's units.
        path: The ``.vtp`` file.
        cell_arrays: Optional integer cell arrays (one value per polyline), e.g. the branch-split form's.
    """
    # deferred: vtk is large (~0.3 s, 100 MB) and only the importer and the tree generator need it
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import vtkPoints  # deferred: as above
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData  # deferred: as above
    from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter  # deferred: as above

    pts = np.ascontiguousarray(np.concatenate([np.asarray(p, dtype=np.float64) for p, _r in paths]))
    rad = np.ascontiguousarray(np.concatenate([np.asarray(r, dtype=np.float64) for _p, r in paths]))
    sizes = np.array([len(p) for p, _r in paths], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    vp = vtkPoints()
    vp.SetData(numpy_to_vtk(pts, deep=True))
    cells = vtkCellArray()
    cells.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                  numpy_to_vtkIdTypeArray(np.arange(len(pts), dtype=np.int64), deep=True))
    poly = vtkPolyData()
    poly.SetPoints(vp)
    poly.SetLines(cells)
    r = numpy_to_vtk(rad, deep=True)
    r.SetName(RADIUS_ARRAY)
    poly.GetPointData().AddArray(r)
    for nm, vals in (cell_arrays or {}).items():
        a = numpy_to_vtk(np.asarray(vals, dtype=np.int32), deep=True)
        a.SetName(nm)
        poly.GetCellData().AddArray(a)
    with atomic_path(path) as tmp:  # whole or not at all
        w = vtkXMLPolyDataWriter()
        w.SetFileName(str(tmp))
        w.SetInputData(poly)
        w.SetDataModeToBinary()
        w.SetCompressorTypeToNone()
        if w.Write() != 1:
            raise OSError(errno.EIO, "vtk could not write the file", str(path))
