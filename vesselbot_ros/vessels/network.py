"""Vessel networks (trees of tubes, planar or in 3-D): the file format, its validation and loading.

A network is a tree of branches, each a centreline polyline with a radius at each point (format in
``docs/vessels.md``); :func:`smooth_centreline` is what its ``smoothing`` and ``sample_spacing_m`` keys mean (the
overlap check samples it).  The tubes' geometry, which tube holds a point: :mod:`vesselbot_ros.vessels.tube_geometry`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from vesselbot_ros.blas_free import interp_spline
from vesselbot_ros.config import (
    OMIT_IF,
    ConfigError,
    check_choice,
    check_finite,
    check_nonnegative,
    check_positive,
    check_range,
    load_dataclass,
    load_yaml,
    resolve_config_path,
    shipped_config_dir,
    to_mapping,
)
from vesselbot_ros.resources import require_fits, spline_setup_cost

__all__ = [
    "BranchParams",
    "CfdParams",
    "FlowPresetParams",
    "SHARE_SUM_TOL",
    "with_flow_preset",
    "VesselNetworkParams",
    "load_network",
    "network_dims",
    "require_planar",
    "smooth_centreline",
    "resolve_network_path",
    "route_to_outlet",
]

#: Folder of the shipped vessel networks.
VESSELS_DIR = Path(__file__).resolve().parents[2] / "config" / "vessels"

#: A blood vessel's lumen radius lies between a capillary's few micrometres and the aorta's ~15 mm (m):
#: a branch's radius outside [MIN_RADIUS_M, MAX_RADIUS_M] is refused (a file in the wrong unit, mostly).
MIN_RADIUS_M = 1.0e-6
MAX_RADIUS_M = 2.0e-2
#: The longest branch, and the largest side of a network's bounding box (m): a vessel tree within a body.
MAX_LENGTH_M = 1.0
#: Memory one smoothed centreline sample costs, all copies made of it (points, radii, arc lengths, the
#: geometry's and the overlap check's copies and trees), rounded up (bytes).
SAMPLE_BYTES = 256.0
#: The overlap check's time per pair of samples of two branches (s; numpy, measured ~20 ns, rounded up).
OVERLAP_SECONDS_PER_PAIR = 4.0e-8
#: ... and per pair of branches (its masks and blocks in Python, s; rounded up).
OVERLAP_SECONDS_PER_BRANCH_PAIR = 1.0e-4
#: The overlap check compares blocks of this many samples of one branch with as many of another (bounded
#: memory: ~100 bytes a pair), skipping the pairs of blocks too far apart to touch.
_OVERLAP_BLOCK = 1024


def _all_zero(values: tuple[float, ...]) -> bool:
    """True if ``values`` is empty or all zero (a branch's ``y_m`` that keeps it in the plane y = 0)."""
    return not any(values)


def _is_zero(value: float) -> bool:
    return bool(value == 0)


def _is_empty(value: tuple[object, ...]) -> bool:
    return not value


def _always(_value: object) -> bool:
    """A network's flow presets are not its geometry nor its field: never in its mapping's hash (a run's preset
    enters the field's key through the ``cfd.outlet_shares`` it sets, :func:`with_flow_preset`)."""
    return True


#: Outlet shares must sum to 1 within this.
SHARE_SUM_TOL = 1.0e-9


def _check_shares(names_key: str, names: tuple[str, ...], shares_key: str, shares: tuple[float, ...]) -> None:
    """Outlet names and their shares: as many, distinct, each share in [0, 1], the sum 1 within SHARE_SUM_TOL
    (none at all is no split)."""
    if not names and not shares:
        return
    if len(shares) != len(names):
        raise ConfigError(f"{shares_key} must give one share per name of {names_key} ({len(names)}), got {list(shares)}")
    for i, n in enumerate(names):
        if names.index(n) != i:
            raise ConfigError(f"{names_key}[{i}] {n!r} is named twice, got {list(names)}")
    for i, v in enumerate(shares):
        check_range(f"{shares_key}[{i}]", v, 0.0, 1.0)
    total = math.fsum(shares)
    if not abs(total - 1.0) <= SHARE_SUM_TOL:
        raise ConfigError(f"{shares_key} must sum to 1 (within {SHARE_SUM_TOL:g}), got {list(shares)} (sum {total:.12g})")


def _norm(d: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Euclidean norm of the rows of ``d`` ((..., 2) as (x, z) or (..., 3) as (x, y, z)).

    In 3-D: ``hypot(hypot(x, z), y)``, which is the planar ``hypot(x, z)`` bit for bit when y = 0.
    """
    if d.shape[-1] == 2:
        return np.hypot(d[..., 0], d[..., 1])
    return np.hypot(np.hypot(d[..., 0], d[..., 2]), d[..., 1])


@dataclasses.dataclass(frozen=True)
class BranchParams:
    """One branch: a centreline polyline with a radius at each point.

    Attributes:
        name: Unique branch name (letters, digits, ``_``).
        parent: Name of the parent branch; ``""`` for the root (inlet) branch.
            A daughter's first point must be its parent's last point.
        x_m: x of the centreline points (m), >= 2 points.
        z_m: z of the centreline points (m), same length.
        radius_m: Lumen radius at each point (m), same length, or one value.
        y_m: y of the centreline points (m), same length; empty (the default)
            means the plane y = 0.  Left out of :func:`~vesselbot_ros.config.to_mapping`
            (and so of every hash) when empty or all zero.
    """

    name: str
    x_m: tuple[float, ...]
    z_m: tuple[float, ...]
    radius_m: tuple[float, ...]
    parent: str = ""
    y_m: tuple[float, ...] = dataclasses.field(default=(), metadata={OMIT_IF: _all_zero})

    def __post_init__(self) -> None:
        if not self.name or not all(c.isalnum() or c == "_" for c in self.name):
            raise ConfigError(f"name must be non-empty letters, digits or '_', got {self.name!r}")
        if len(self.x_m) < 2:
            raise ConfigError(f"x_m needs at least 2 points, got {list(self.x_m)}")
        if len(self.z_m) != len(self.x_m):
            raise ConfigError(f"z_m must have as many points as x_m ({len(self.x_m)}), got {len(self.z_m)}")
        if len(self.radius_m) not in (1, len(self.x_m)):
            raise ConfigError(f"radius_m must have 1 or {len(self.x_m)} values, got {len(self.radius_m)}")
        for i, v in enumerate(self.x_m):
            check_finite(f"x_m[{i}]", v)
        for i, v in enumerate(self.z_m):
            check_finite(f"z_m[{i}]", v)
        if self.y_m and len(self.y_m) != len(self.x_m):
            raise ConfigError(f"y_m must have as many points as x_m ({len(self.x_m)}) or none (the plane y = 0), "
                              f"got {len(self.y_m)}")
        for i, v in enumerate(self.y_m):
            check_finite(f"y_m[{i}]", v)
        for i, v in enumerate(self.radius_m):
            check_positive(f"radius_m[{i}]", v)
            if not MIN_RADIUS_M <= v <= MAX_RADIUS_M:
                raise ConfigError(f"radius_m[{i}] must be a blood vessel's lumen radius, between {MIN_RADIUS_M:g} and "
                                  f"{MAX_RADIUS_M:g} m, got {v!r} (is the unit metres?)")
        if self.is_planar:
            pts = np.column_stack([self.x_m, self.z_m])
            seg = np.hypot(*np.diff(pts, axis=0).T)
            keys = "x_m, z_m"
        else:
            pts = self.points_3d()
            seg = _norm(np.diff(pts, axis=0))
            keys = "x_m, y_m, z_m"
        if np.any(seg <= 0.0):
            i = int(np.argmin(seg))
            raise ConfigError(f"{keys}: points must be distinct, got a repeated point at index {i + 1}: {pts[i + 1].tolist()}")
        length = float(seg.sum())
        if not length <= MAX_LENGTH_M:
            raise ConfigError(f"{keys}: a branch is at most {MAX_LENGTH_M:g} m long, got {length:.6g} m "
                              "(is the unit metres?)")

    @property
    def is_planar(self) -> bool:
        """True if the branch lies in the plane y = 0 (``y_m`` empty or all zero)."""
        return _all_zero(self.y_m)

    def points_3d(self) -> npt.NDArray[np.float64]:
        """(n, 3) centreline points (x, y, z) (m); y = 0 without ``y_m``."""
        y = self.y_m if self.y_m else (0.0,) * len(self.x_m)
        return np.column_stack([self.x_m, y, self.z_m]).astype(np.float64)

    def radii(self) -> npt.NDArray[np.float64]:
        """(n,) radius at each point (m)."""
        return np.broadcast_to(np.asarray(self.radius_m, dtype=np.float64), (len(self.x_m),)).copy()


@dataclasses.dataclass(frozen=True)
class CfdParams:
    """How the network's steady flow is computed (:mod:`vesselbot_ros.vessels.cfd`).

    Attributes:
        inlet_centreline_velocity_m_per_s: Centreline velocity of the parabolic
            inflow of the steady solve (m/s); sets its Reynolds number.  The
            plant scales the field (normalised to an inlet centreline velocity of
            1) by ``physics.flow.centreline_velocity_m_per_s`` and the pulse (12).
        mesh_size_m: Target element size of the gmsh mesh (m).
        grid_spacing_m: Spacing of the regular sampling grid (m).
        grid_margin_m: Margin of the grid around the network's bounding box (m).
        outlet_split: ``murray``: each outlet carries a share of the inflow
            proportional to r^3 (Murray's law, the 3-D flow the 2-D solve
            stands for); ``area``: proportional to r^2 (same mean velocity);
            ``shares``: the shares ``outlet_shares`` of the outlets ``share_outlets``
            (set by a flow preset, :func:`with_flow_preset`).
        share_outlets: With ``outlet_split: shares``: every outlet branch's name, once.
        outlet_shares: ... its share of the inflow (-), summing to 1.  Both left out of
            :func:`~vesselbot_ros.config.to_mapping` (and every hash) when empty.
        diameter_smoothing_m: Gaussian width (m) with which the sampled local
            diameter (the meshed lumen's local thickness) and viscosity are
            smoothed: they have kinks through a junction, and the pulsating wall
            moves out by D eps / 2.
        picard_max_iterations: Cap on the Picard (Oseen) iterations.
        picard_tol: Relative change of the velocity at which Picard stops.
        mesh_size_3d_m: A 3-D tree's solve (:mod:`vesselbot_ros.vessels.tree_cfd`): largest tetrahedron edge in
            the lumen (m); 0 (the default): 1.2 ``mesh_size_m``.
        wall_elements_per_circle_3d: ... elements around a circumference of its wall; 0: 32.
        grid_spacing_3d_m: ... spacing of the 3-D plant's grid of wall and flow samples
            (:mod:`vesselbot_ros.vessels.tree_field`, m); 0: 0.1 mm.
        The three 3-D keys are left out of :func:`~vesselbot_ros.config.to_mapping` (and every hash) at 0.
    """

    inlet_centreline_velocity_m_per_s: float = 0.025
    mesh_size_m: float = 1.0e-4
    grid_spacing_m: float = 2.5e-5
    grid_margin_m: float = 5.0e-4
    outlet_split: Literal["murray", "area", "shares"] = "murray"
    diameter_smoothing_m: float = 2.5e-4
    picard_max_iterations: int = 30
    picard_tol: float = 1.0e-9
    mesh_size_3d_m: float = dataclasses.field(default=0.0, metadata={OMIT_IF: _is_zero})
    wall_elements_per_circle_3d: int = dataclasses.field(default=0, metadata={OMIT_IF: _is_zero})
    grid_spacing_3d_m: float = dataclasses.field(default=0.0, metadata={OMIT_IF: _is_zero})
    share_outlets: tuple[str, ...] = dataclasses.field(default=(), metadata={OMIT_IF: _is_empty})
    outlet_shares: tuple[float, ...] = dataclasses.field(default=(), metadata={OMIT_IF: _is_empty})

    def __post_init__(self) -> None:
        check_positive("inlet_centreline_velocity_m_per_s", self.inlet_centreline_velocity_m_per_s)
        check_range("mesh_size_3d_m", self.mesh_size_3d_m, 0.0, 0.01)
        check_range("grid_spacing_3d_m", self.grid_spacing_3d_m, 0.0, 0.002)
        if self.wall_elements_per_circle_3d != 0 and not 6 <= self.wall_elements_per_circle_3d <= 128:
            raise ConfigError(f"wall_elements_per_circle_3d must be 0 (32) or in [6, 128], "
                              f"got {self.wall_elements_per_circle_3d!r}")
        check_positive("mesh_size_m", self.mesh_size_m)
        check_positive("grid_spacing_m", self.grid_spacing_m)
        check_range("grid_margin_m", self.grid_margin_m, 0.0, 0.1)
        check_choice("outlet_split", self.outlet_split, ("murray", "area", "shares"))
        if (self.outlet_split == "shares") != bool(self.share_outlets):
            raise ConfigError(f"share_outlets and outlet_shares go with outlet_split: shares and only with it, got "
                              f"outlet_split={self.outlet_split!r}, share_outlets={list(self.share_outlets)}")
        _check_shares("share_outlets", self.share_outlets, "outlet_shares", self.outlet_shares)
        check_range("diameter_smoothing_m", self.diameter_smoothing_m, 0.0, 0.01)
        if self.picard_max_iterations < 1:
            raise ConfigError(f"picard_max_iterations must be >= 1, got {self.picard_max_iterations!r}")
        check_positive("picard_tol", self.picard_tol)


@dataclasses.dataclass(frozen=True)
class FlowPresetParams:
    """A physiological flow of a network, from a cited source (``flow_presets`` of the file; docs/vessels.md).

    Mapped onto the paper's waveform (12), ``v = V_f (1 + a_f sin(omega_f t + phi_f)) p``, whose cycle mean is
    V_f and whose peak is V_f (1 + a_f): V_f = 2 ``mean_velocity_m_per_s`` (the Poiseuille centreline velocity of
    that mean velocity, the inflow profile of the CFD), a_f = ``peak_centreline_velocity_m_per_s`` / V_f - 1 (or
    ``pulsatility`` as given), omega_f = 2 pi ``heart_rate_per_min`` / 60.  One harmonic cannot hold a source's
    mean, peak and end-diastolic velocities at once: the minimum is V_f (1 - a_f), whatever the source's.

    Attributes:
        name: The preset's name (``physics.flow.preset``): letters, digits, ``_``.
        source: The citation (free text; the file's comments give the arithmetic).
        mean_velocity_m_per_s: Cycle- and cross-section-averaged velocity of the inflow (m/s), > 0.
        peak_centreline_velocity_m_per_s: Peak systolic centreline (spectral peak) velocity of the inflow
            (m/s), >= 2 ``mean_velocity_m_per_s``; or
        pulsatility: a_f as given (-), >= 0 (exactly one of the two).
        heart_rate_per_min: Heart rate (1/min), in (0, 300].
        outlets: Every outlet branch of the network, once (empty: the network's ``cfd.outlet_split`` stays).
        outlet_shares: Each outlet's share of the inflow (-), in [0, 1], summing to 1 within 1e-9.
    """

    name: str
    source: str
    mean_velocity_m_per_s: float
    heart_rate_per_min: float
    peak_centreline_velocity_m_per_s: float | None = None
    pulsatility: float | None = None
    outlets: tuple[str, ...] = ()
    outlet_shares: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not self.name or not all(c.isalnum() or c == "_" for c in self.name):
            raise ConfigError(f"name must be non-empty letters, digits or '_', got {self.name!r}")
        if not isinstance(self.source, str) or not self.source.strip():
            raise ConfigError(f"source must cite where the numbers come from, got {self.source!r}")
        check_positive("mean_velocity_m_per_s", self.mean_velocity_m_per_s)
        check_range("heart_rate_per_min", self.heart_rate_per_min, 0.0, 300.0, lo_open=True)
        if (self.peak_centreline_velocity_m_per_s is None) == (self.pulsatility is None):
            raise ConfigError(f"peak_centreline_velocity_m_per_s or pulsatility: give exactly one, got "
                              f"peak_centreline_velocity_m_per_s={self.peak_centreline_velocity_m_per_s!r}, "
                              f"pulsatility={self.pulsatility!r}")
        if self.peak_centreline_velocity_m_per_s is not None:
            check_positive("peak_centreline_velocity_m_per_s", self.peak_centreline_velocity_m_per_s)
            if self.peak_centreline_velocity_m_per_s < self.centreline_velocity_m_per_s:
                raise ConfigError(f"peak_centreline_velocity_m_per_s must be >= the mean centreline velocity "
                                  f"2 mean_velocity_m_per_s = {self.centreline_velocity_m_per_s!r}, got "
                                  f"{self.peak_centreline_velocity_m_per_s!r}")
        if self.pulsatility is not None:
            check_nonnegative("pulsatility", self.pulsatility)
        if bool(self.outlets) != bool(self.outlet_shares):
            raise ConfigError(f"outlets and outlet_shares go together, got outlets={list(self.outlets)}, "
                              f"outlet_shares={list(self.outlet_shares)}")
        _check_shares("outlets", self.outlets, "outlet_shares", self.outlet_shares)

    @property
    def centreline_velocity_m_per_s(self) -> float:
        """V_f (m/s): the Poiseuille centreline velocity of the mean velocity, 2 ``mean_velocity_m_per_s``."""
        return 2.0 * self.mean_velocity_m_per_s

    @property
    def pulsatility_value(self) -> float:
        """a_f (-): ``pulsatility``, else peak / V_f - 1."""
        if self.pulsatility is not None:
            return self.pulsatility
        assert self.peak_centreline_velocity_m_per_s is not None  # one of the two (checked)
        return self.peak_centreline_velocity_m_per_s / self.centreline_velocity_m_per_s - 1.0

    @property
    def angular_frequency_rad_per_s(self) -> float:
        """omega_f = 2 pi HR / 60 (rad/s)."""
        return 2.0 * math.pi * (self.heart_rate_per_min / 60.0)  # 60 /min: 2 pi itself, Table III's omega_f

    def flow_values(self) -> dict[str, float]:
        """The ``physics.flow`` keys the preset sets."""
        return {"centreline_velocity_m_per_s": self.centreline_velocity_m_per_s,
                "pulsatility": self.pulsatility_value,
                "angular_frequency_rad_per_s": self.angular_frequency_rad_per_s}


@dataclasses.dataclass(frozen=True)
class VesselNetworkParams:
    """A vessel network (tree of branches) and how its flow is computed.

    Attributes:
        name: Network name.
        branches: The branches, root first or in any order.
        smoothing: ``spline`` (C2 cubic through the points) or ``none``.
        sample_spacing_m: Spacing of the smoothed centreline samples (m).
        cfd: CFD settings.
        flow_presets: Physiological flows of this tree (:class:`FlowPresetParams`), by name; never in
            :func:`~vesselbot_ros.config.to_mapping` (nor so in a hash): see :func:`with_flow_preset`.
    """

    name: str
    branches: tuple[BranchParams, ...]
    smoothing: Literal["spline", "none"] = "spline"
    sample_spacing_m: float = 2.0e-5
    cfd: CfdParams = dataclasses.field(default_factory=CfdParams)
    flow_presets: tuple[FlowPresetParams, ...] = dataclasses.field(default=(), metadata={OMIT_IF: _always})

    def __post_init__(self) -> None:
        if not self.name or not all(c.isalnum() or c in "_-." for c in self.name):
            raise ConfigError(f"name must be non-empty letters, digits, '_', '-', '.', got {self.name!r}")
        check_choice("smoothing", self.smoothing, ("spline", "none"))
        check_positive("sample_spacing_m", self.sample_spacing_m)
        if not self.branches:
            raise ConfigError("branches must list at least one branch, got []")
        names = [b.name for b in self.branches]
        for i, n in enumerate(names):
            if names.index(n) != i:
                raise ConfigError(f"branches[{i}].name {n!r} is used twice (also branches[{names.index(n)}])")
        roots = [i for i, b in enumerate(self.branches) if b.parent == ""]
        if len(roots) != 1:
            raise ConfigError(f"exactly one branch must have parent '' (the inlet branch), got {[names[i] for i in roots]}")
        by_name = {b.name: b for b in self.branches}
        planar = self.is_planar
        for i, b in enumerate(self.branches):
            if b.parent == "":
                continue
            if b.parent not in by_name:
                raise ConfigError(f"branches[{i}].parent {b.parent!r} is not a branch name; names: {names}")
            par = by_name[b.parent]
            if planar:
                gap = math.hypot(b.x_m[0] - par.x_m[-1], b.z_m[0] - par.z_m[-1])
                end, start = [par.x_m[-1], par.z_m[-1]], [b.x_m[0], b.z_m[0]]
            else:
                end, start = par.points_3d()[-1].tolist(), b.points_3d()[0].tolist()
                gap = math.dist(end, start)
            if gap > 1e-9:
                raise ConfigError(f"branches[{i}] ({b.name!r}) must start at the last point of its parent {b.parent!r} "
                                  f"({end}), got {start}")
        # cycles: every branch must reach the root
        for i, b in enumerate(self.branches):
            seen, cur = set(), b
            while cur.parent:
                if cur.name in seen:
                    raise ConfigError(f"branches[{i}] ({b.name!r}): parent chain has a cycle through {cur.name!r}")
                seen.add(cur.name)
                cur = by_name[cur.parent]
        pts = np.concatenate([b.points_3d() for b in self.branches])
        extent = pts.max(axis=0) - pts.min(axis=0)
        if not float(extent.max()) <= MAX_LENGTH_M:
            raise ConfigError(f"branches: a network spans at most {MAX_LENGTH_M:g} m along x, y and z, got "
                              f"{[float(f'{e:.6g}') for e in extent]} m (is the unit metres?)")
        outlets = [b.name for b in self.branches if not any(c.parent == b.name for c in self.branches)]
        for key, named in [("cfd.share_outlets", self.cfd.share_outlets)] + [
                (f"flow_presets[{i}].outlets", p.outlets) for i, p in enumerate(self.flow_presets)]:
            for j, n in enumerate(named):
                if n not in outlets:
                    raise ConfigError(f"{key}[{j}] {n!r} is not an outlet of network {self.name!r}; outlets: {outlets}")
            if named and len(named) != len(outlets):
                missing = [n for n in outlets if n not in named]
                raise ConfigError(f"{key} must name every outlet of network {self.name!r} ({outlets}), got "
                                  f"{list(named)} (missing {missing})")
        preset_names = [p.name for p in self.flow_presets]
        for i, n in enumerate(preset_names):
            if preset_names.index(n) != i:
                raise ConfigError(f"flow_presets[{i}].name {n!r} is used twice (also flow_presets[{preset_names.index(n)}])")
        _check_sizes(self)
        _check_overlaps(self)

    def flow_preset(self, name: str) -> FlowPresetParams:
        """The flow preset ``name``.

        Raises:
            ConfigError: no such preset (the message lists the network's presets).
        """
        for p in self.flow_presets:
            if p.name == name:
                return p
        raise ConfigError(f"physics.flow.preset: network {self.name!r} has no flow preset {name!r}; its presets: "
                          f"{[p.name for p in self.flow_presets]}")

    @property
    def is_planar(self) -> bool:
        """True if every branch lies in the plane y = 0: the network the 2-D consumers take."""
        return all(b.is_planar for b in self.branches)

    @property
    def is_3d(self) -> bool:
        """True if the file writes the tree in three dimensions (some branch gives ``y_m``, even all zero): the
        network the plant takes on three axes (:mod:`vesselbot_ros.vessels.tree_field`); the planar plant takes the others."""
        return any(b.y_m for b in self.branches)

    @property
    def root(self) -> BranchParams:
        """The inlet branch."""
        return next(b for b in self.branches if b.parent == "")

    def children(self, name: str) -> list[BranchParams]:
        """Daughters of branch ``name``."""
        return [b for b in self.branches if b.parent == name]

    @property
    def outlets(self) -> list[str]:
        """Names of the branches that end at an outlet (no daughters), in file order."""
        return [b.name for b in self.branches if not self.children(b.name)]

    def geometry_hash(self) -> str:
        """sha256 of the geometry (branches, smoothing, sampling) and CFD settings."""
        text = json.dumps(to_mapping(self), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()


def _check_sizes(net: VesselNetworkParams) -> None:
    """Refuse, before any sample is made, a network whose smoothed centrelines would not fit.

    The samples (``ceil(chord / sample_spacing_m) + 1`` a branch), the smoothing spline's dense solve through a
    branch's points and the overlap check's pairs of samples are estimated and bounded by
    :func:`vesselbot_ros.resources.require_fits`.
    """
    nb = len(net.branches)
    require_fits("branches", f"{nb} branches", SAMPLE_BYTES * nb, OVERLAP_SECONDS_PER_BRANCH_PAIR * nb * (nb - 1) / 2.0,
                 what="the overlap check of every pair of branches", hint="split the tree into several networks")
    samples: list[float] = []
    for b in net.branches:
        p = b.points_3d()
        chord = float(_norm(np.diff(p, axis=0)).sum())
        samples.append(max(2.0, math.ceil(chord / net.sample_spacing_m) + 1.0))
    total = sum(samples)
    pairs = (total * total - sum(n * n for n in samples)) / 2.0
    require_fits("sample_spacing_m", net.sample_spacing_m, SAMPLE_BYTES * total, OVERLAP_SECONDS_PER_PAIR * pairs,
                 what=f"the network's {total:.3g} centreline samples (and the overlap check of their pairs)",
                 hint="raise sample_spacing_m")
    if net.smoothing == "spline":
        i = max(range(len(net.branches)), key=lambda j: len(net.branches[j].x_m))
        n = len(net.branches[i].x_m)
        require_fits(f"branches[{i}].x_m", f"{n} points", *spline_setup_cost(n),
                     what=f"branch {net.branches[i].name!r}'s smoothing spline", hint="thin its points or use smoothing: none")


def _blocks(q: npt.NDArray[np.float64], r: npt.NDArray[np.float64]
            ) -> list[tuple[int, npt.NDArray[np.float64], npt.NDArray[np.float64], float]]:
    """(start, box low, box high, largest radius) of each block of :data:`_OVERLAP_BLOCK` consecutive samples."""
    out = []
    for lo in range(0, len(q), _OVERLAP_BLOCK):
        qq = q[lo:lo + _OVERLAP_BLOCK]
        out.append((lo, qq.min(axis=0), qq.max(axis=0), float(r[lo:lo + _OVERLAP_BLOCK].max())))
    return out


def _worst_overlap(qa: npt.NDArray[np.float64], ra: npt.NDArray[np.float64], qb: npt.NDArray[np.float64],
                   rb: npt.NDArray[np.float64]) -> tuple[float, int, int, float, float] | None:
    """The pair of samples whose tubes overlap most, ``(need - d, ia, ib, d, need)``, or None if none do.

    ``np.argmax`` of ``need - d`` over all (ia, ib) (its first maximum), in blocks of samples: two blocks
    whose boxes lie farther apart than their largest radii's sum hold no overlap and are skipped, so the memory
    is one block pair's and the time grows with the pairs that come close, not with all of them.
    """
    best: tuple[float, int, int, float, float] | None = None
    bb = _blocks(qb, rb)
    for la, alo, ahi, amax in _blocks(qa, ra):
        for lb, blo, bhi, bmax in bb:
            gap = np.maximum(0.0, np.maximum(blo - ahi, alo - bhi))
            if float(_norm(gap[None, :])[0]) >= amax + bmax:
                continue
            d = _norm(qa[la:la + _OVERLAP_BLOCK, None, :] - qb[None, lb:lb + _OVERLAP_BLOCK, :])
            need = ra[la:la + _OVERLAP_BLOCK, None] + rb[None, lb:lb + _OVERLAP_BLOCK]
            if not (d < need).any():
                continue
            excess = need - d
            k = int(np.argmax(excess))
            ka, kb = np.unravel_index(k, d.shape)
            cand = (float(excess.flat[k]), la + int(ka), lb + int(kb), float(d[ka, kb]), float(need[ka, kb]))
            if best is None or cand[0] > best[0] or (cand[0] == best[0] and cand[1:3] < best[1:3]):
                best = cand  # ties: the first in (ia, ib) order, as one argmax over the whole array
    return best


def _check_overlaps(net: VesselNetworkParams) -> None:
    """Raise ConfigError naming two branches whose tubes overlap away from their common node.

    Planar networks are checked in the XZ plane (as before ``y_m``), others on their 3-D centrelines.
    """
    planar = net.is_planar
    cl = {b.name: smooth_centreline(b, net.smoothing, net.sample_spacing_m, 2 if planar else 3) for b in net.branches}
    by_name = {b.name: b for b in net.branches}
    for i, a in enumerate(net.branches):
        for b in net.branches[i + 1:]:
            pa, ra, _sa = cl[a.name]
            pb, rb, _sb = cl[b.name]
            related = a.parent == b.name or b.parent == a.name or (a.parent == b.parent and a.parent != "")
            ma = np.ones(len(pa), dtype=bool)
            mb = np.ones(len(pb), dtype=bool)
            if related:
                # near the shared node the tubes meet by construction: skip one junction length
                node = pa[-1] if b.parent == a.name else (pb[-1] if a.parent == b.name else pa[0])
                reach = 3.0 * (ra.max() + rb.max())
                ma = _norm(pa - node) > reach
                mb = _norm(pb - node) > reach
                if b.parent == a.name or a.parent == b.name:
                    continue  # a parent and its daughter only meet at the node (the daughter leaves it)
            if not ma.any() or not mb.any():
                continue
            qa, qb = pa[ma], pb[mb]
            rqa, rqb = ra[ma], rb[mb]
            worst = _worst_overlap(qa, rqa, qb, rqb)
            if worst is not None:
                _e, ia, ib, dist, sum_r = worst
                where = (0.5 * (qa[ia] + qb[ib])).tolist()
                axes = "x, z" if planar else "x, y, z"
                at = ", ".join(f"{v:.6g}" for v in where)
                raise ConfigError(f"branches {a.name!r} and {by_name[b.name].name!r} overlap near ({axes}) = "
                                  f"({at}) m: centrelines {dist:.6g} m apart, "
                                  f"radii sum {sum_r:.6g} m")


def smooth_centreline(b: BranchParams, smoothing: str, spacing_m: float, dims: int = 2
                      ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(points (n, dims) m, radius (n,) m, arc length (n,) m) of the smoothed centreline of ``b``.

    The C2 cubic (natural) interpolating spline through the points in the chord-length parameter
    (quadratic through 3 points, the polyline for 2 points or ``smoothing: none``), sampled at
    ``ceil(chord / spacing_m) + 1`` equal steps of the chord parameter; the radius linear in it.
    ``dims`` 3 gives (x, y, z) columns; 2 gives (x, z) of a planar branch, the same bits as its 3-D
    samples' x and z (chord lengths are ``hypot(hypot(dx, dz), dy)``, which is ``hypot(dx, dz)`` at y = 0).

    Raises:
        ConfigError: if ``dims`` is 2 and ``b`` leaves the plane y = 0.
    """
    if dims == 2 and not b.is_planar:
        raise ConfigError(f"branch {b.name!r} is not planar (y_m = {list(b.y_m)}): its centreline is 3-D (dims=3)")
    pts = b.points_3d()
    if dims == 2:  # axis count at the geometry's edge: the plane's (x, z) columns
        pts = np.ascontiguousarray(pts[:, ::2])
    rad = b.radii()
    chord = np.concatenate([[0.0], np.cumsum(_norm(np.diff(pts, axis=0)))])
    n = max(2, int(math.ceil(chord[-1] / spacing_m)) + 1)
    u = np.linspace(0.0, chord[-1], n)
    if smoothing == "spline" and len(pts) >= 3:
        # make_interp_spline's spline, solved without LAPACK: the same centreline bits on every CPU
        k = 3 if len(pts) >= 4 else 2
        out = interp_spline(chord, pts, k=k)(u)
    else:
        out = np.column_stack([np.interp(u, chord, pts[:, j]) for j in range(dims)])
    r = np.interp(u, chord, rad)
    s = np.concatenate([[0.0], np.cumsum(_norm(np.diff(out, axis=0)))])
    return out, r, s


def require_planar(net: VesselNetworkParams, consumer: str) -> None:
    """Refuse a network that leaves the plane y = 0 in a 2-D consumer, in one line.

    Args:
        net: The network.
        consumer: What refuses it (``"the 2-D CFD"``, ``"the 2-D plant"``).

    Raises:
        ConfigError: naming the network, its first non-planar branch and ``consumer``.
    """
    for b in net.branches:
        if not b.is_planar:
            y = max(b.y_m, key=abs)
            raise ConfigError(f"vessel network {net.name!r} is not planar (branch {b.name!r} leaves the plane y = 0, "
                              f"|y| up to {abs(y):.6g} m): {consumer} takes XZ networks only (the plant takes this tree on three axes)")


def resolve_network_path(source: str) -> Path:
    """Path of a network file: as given (absolute or relative to the working directory), else in the
    shipped configuration (``config/vessels/...`` of a checkout, or of ``<prefix>/share/vesselbot_ros``
    for an installed wheel: :func:`vesselbot_ros.config.shipped_config_dir`), else a shipped name
    (``paper_iiic_artery``)."""
    p = Path(source)
    if p.is_file():
        return p
    vessels = shipped_config_dir() / "vessels"
    repo = vessels.parents[1]
    for cand in (resolve_config_path(source), vessels / source, vessels / f"{source}.yaml"):
        if cand.is_file():
            return cand
    raise ConfigError(f"vessel network {source!r} does not exist (looked in the working directory, {repo}, {vessels})")


def load_network(source: str) -> VesselNetworkParams:
    """Load and validate a network YAML file (see :func:`resolve_network_path`); cached per file version."""
    path = resolve_network_path(source).resolve()
    st = path.stat()
    return _load_network_cached(str(path), st.st_mtime_ns, st.st_size)


def network_dims(source: str) -> int:
    """The axis count of the vessel a physics section names: 3 for a 3-D tree (its file gives ``y_m``), else 2 (no
    network, or a planar one).  A network that does not load counts as planar; its own check names the file."""
    if not source:
        return 2
    try:
        return 3 if load_network(source).is_3d else 2
    except ConfigError:
        return 2


@functools.lru_cache(maxsize=32)
def _load_network_cached(path: str, _mtime_ns: int, _size: int) -> VesselNetworkParams:
    try:
        return load_dataclass(VesselNetworkParams, load_yaml(path), "")
    except ConfigError as exc:
        raise ConfigError(f"vessel network {str(path)!r}: {exc}") from None


def with_flow_preset(net: VesselNetworkParams, name: str) -> VesselNetworkParams:
    """``net`` as a run with ``physics.flow.preset: name`` solves it: its CFD block taking the preset's outlet
    shares (``cfd.outlet_split: shares``, a field of its own key), or ``net`` itself for ``""`` or a preset
    without shares (the network's own split stays).

    Raises:
        ConfigError: ``net`` has no preset ``name``.
    """
    if not name:
        return net
    preset = net.flow_preset(name)
    if not preset.outlets:
        return net
    cfd = dataclasses.replace(net.cfd, outlet_split="shares", share_outlets=preset.outlets,
                              outlet_shares=preset.outlet_shares)
    return dataclasses.replace(net, cfd=cfd)


def route_to_outlet(net: VesselNetworkParams, outlet: str) -> list[str]:
    """Branch sequence from the inlet branch to the outlet branch ``outlet`` (over the tree)."""
    by_name = {b.name: b for b in net.branches}
    if outlet not in by_name:
        raise ConfigError(f"route outlet {outlet!r} is not a branch of network {net.name!r}; branches: {list(by_name)}")
    seq = [outlet]
    while by_name[seq[-1]].parent:
        seq.append(by_name[seq[-1]].parent)
    return seq[::-1]
