"""Campaign spec: a base scenario plus what varies, loaded strictly from YAML.

A campaign file (``config/campaigns/*.yaml``) names a base scenario and the
values that vary across runs::

    name: vf_error_seeds                 # output folder name
    base: ../sound_small_artery.yaml     # scenario YAML, relative to this file
    overrides:                           # fixed changes to the base (dotted keys)
      sim.duration_s: 2.0
    seeds: {start: 0, count: 100}        # imager noise seeds (or a list: [0, 3, 7])
    variants:                            # named sets of changes that go together (a controller
      table3_gains: {}                   #   with its observer and gains): one more grid axis,
      ekf_flow_estimate:                 #   the column ``variant`` holds the name
        observer.kind: ekf
        controller.gains.k1: 150.0
    grid:                                # every combination of these values
      controller.sample_hold: [none, midpoint]
    samples:                             # random draws over any scenario key
      count: 50
      rng_seed: 2012                     # seed of the sampler (not of the runs)
      paired_with_seeds: false           # false: every draw x every seed; true: draw i uses seeds[i]
      params:
        physics.blood.relative_permittivity: {distribution: uniform, low: 45, high: 77}
        physics.blood.constant_viscosity_Pa_s: {distribution: log_uniform, low: 0.008, high: 0.02}
        physics.robot.radius_m: {distribution: normal, mean: 250.0e-6, std: 5.0e-6}
    keep_timeseries: {seeds: [0], runs: []}   # per-run time series kept for these seeds / run indices
    chunk_size: 0                        # runs per Dask task; 0 = automatic
    run_timeout_s: 300.0                 # wall-clock budget of one run (s); a run over it is recorded
                                         #   with status ``timeout``; omitted or null = no budget

The runs are every variant x grid point x every draw x every seed (or x the
paired seed), in that nesting order; the position in that order is the run ``index``.  Keys
are dotted paths into :class:`~vesselbot_ros.sim.scenario.Scenario` (a key
inside ``model.overrides`` is free-form, checked when the scenario is built).  Each change goes through
the scenario's one override path (:func:`~vesselbot_ros.sim.scenario.overridden`), as ``--set`` does: a value
replaces what is at its key.
Like every config, the file goes through :func:`vesselbot_ros.config.load_dataclass`:
unknown keys are errors, and every error names the key and the value.  Grid
values and the centre of each distribution are checked against the scenario
when the spec is loaded, so a typo fails before any run starts; a random draw
that falls outside a key's valid range (a normal tail) is a failed run,
recorded with its error.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import types
import typing
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vesselbot_ros.config import (
    RESOLVE_TYPE,
    ConfigError,
    check_choice,
    check_finite,
    check_positive,
    load_dataclass,
    load_yaml,
)
from vesselbot_ros.resources import require_fits
from vesselbot_ros.sim.scenario import Scenario, load_scenario_mapping, overridden, scenario_from_mapping

__all__ = [
    "Distribution",
    "SeedRange",
    "SampleSpec",
    "KeepSpec",
    "CampaignSpec",
    "RunPoint",
    "load_campaign_spec",
    "campaign_spec_from_mapping",
    "check_scenario_key",
    "expand_points",
    "group_mapping",
]

DISTRIBUTIONS = ("uniform", "normal", "log_uniform")


@dataclasses.dataclass(frozen=True)
class Distribution:
    """One random parameter.

    Attributes:
        distribution: ``uniform`` on [low, high), ``normal`` (mean, std) or
            ``log_uniform`` (log of the value uniform on [log low, log high); low > 0).
        low, high: Bounds of ``uniform`` and ``log_uniform`` (the key's unit).
        mean, std: Mean and standard deviation of ``normal`` (the key's unit).
    """

    distribution: Literal["uniform", "normal", "log_uniform"]
    low: float | None = None
    high: float | None = None
    mean: float | None = None
    std: float | None = None

    def __post_init__(self) -> None:
        check_choice("distribution", self.distribution, DISTRIBUTIONS)
        wants = ("mean", "std") if self.distribution == "normal" else ("low", "high")
        for name in ("low", "high", "mean", "std"):
            value = getattr(self, name)
            if name in wants:
                if value is None:
                    raise ConfigError(f"{name} is required for distribution {self.distribution!r}")
                check_finite(name, value)
            elif value is not None:
                raise ConfigError(f"{name} does not apply to distribution {self.distribution!r}, got {value!r}")
        if self.distribution == "normal":
            check_positive("std", self.std)  # type: ignore[arg-type]  # required for normal: checked above
            return
        assert self.low is not None and self.high is not None
        if self.high <= self.low:
            raise ConfigError(f"high must be > low ({self.low!r}), got {self.high!r}")
        if self.distribution == "log_uniform":
            check_positive("low", self.low)

    def centre(self) -> float:
        """A typical value (mean, midpoint or geometric mean), used to check the key."""
        if self.distribution == "normal":
            return float(self.mean)  # type: ignore[arg-type]  # required for normal (__post_init__)
        assert self.low is not None and self.high is not None
        if self.distribution == "log_uniform":
            return math.sqrt(self.low * self.high)
        return 0.5 * (self.low + self.high)

    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` draws from ``rng`` (float64)."""
        if self.distribution == "normal":
            assert self.mean is not None and self.std is not None
            return rng.normal(self.mean, self.std, n)
        assert self.low is not None and self.high is not None
        if self.distribution == "log_uniform":
            return np.exp(rng.uniform(math.log(self.low), math.log(self.high), n))
        return rng.uniform(self.low, self.high, n)


@dataclasses.dataclass(frozen=True)
class SeedRange:
    """Seeds ``start, start + 1, ..., start + count - 1``."""

    start: int = 0
    count: int = 1

    def __post_init__(self) -> None:
        if self.start < 0:
            raise ConfigError(f"start must be >= 0, got {self.start!r}")
        if self.count < 1:
            raise ConfigError(f"count must be >= 1, got {self.count!r}")


@dataclasses.dataclass(frozen=True)
class SampleSpec:
    """Random draws over scenario keys.

    Attributes:
        count: Number of draws (0 = no sampling).
        rng_seed: Seed of the sampler's ``numpy.random.Generator``; the draws
            are made key by key in the order the keys are written.
        paired_with_seeds: ``false``: every draw runs with every seed;
            ``true``: draw ``i`` runs with ``seeds[i]`` only (needs as many
            seeds as draws), so noise and parameters vary together.
        params: Dotted scenario key -> :class:`Distribution`.
    """

    count: int = 0
    rng_seed: int = 0
    paired_with_seeds: bool = False
    params: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.count < 0:
            raise ConfigError(f"count must be >= 0, got {self.count!r}")
        if self.rng_seed < 0:
            raise ConfigError(f"rng_seed must be >= 0, got {self.rng_seed!r}")
        params = {str(k): load_dataclass(Distribution, v, f"params.{k}") for k, v in self.params.items()}
        object.__setattr__(self, "params", params)
        if self.count and not params:
            raise ConfigError(f"params must name at least one key when count > 0, got {self.params!r}")
        if params and not self.count:
            raise ConfigError(f"count must be >= 1 when params are given, got {self.count!r}")


@dataclasses.dataclass(frozen=True)
class KeepSpec:
    """Which runs keep their full time series (``timeseries/<run_id>.parquet``).

    Attributes:
        seeds: Keep every run with one of these seeds.
        runs: Keep the runs with these indices.
    """

    seeds: tuple[int, ...] = ()
    runs: tuple[int, ...] = ()


@dataclasses.dataclass(frozen=True)
class CampaignSpec:
    """A campaign (see the module docstring for the file format).

    Attributes:
        name: Campaign name (output folder ``out/campaigns/<name>``).
        base: Base scenario YAML; a relative path is taken from the spec file's folder.
        overrides: Fixed changes to the base, dotted key -> value.
        seeds: Imager noise seeds: a list or ``{start, count}`` (loaded as a tuple or a :class:`SeedRange`).
        variants: Name -> {dotted key: value}: named sets of changes applied together
            (e.g. an observer with its controller and gains); every variant runs with every
            grid point, draw and seed, and the results' ``variant`` column holds its name.
        grid: Dotted key -> list of values; every combination is run.
        samples: Random draws (:class:`SampleSpec`).
        keep_timeseries: Runs whose time series are kept (:class:`KeepSpec`).
        chunk_size: Runs per Dask task; 0 = shrinking chunks sized from the runs left, the workers and the
            measured run time (:class:`vesselbot_ros.campaign.engine.ChunkSizer`).
        run_timeout_s: Wall-clock budget of each run (s), None = none: a run over it is
            stopped and recorded with status ``timeout`` (:func:`vesselbot_ros.campaign.engine.execute`).
    """

    name: str
    base: str
    overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    seeds: Any = (0,)
    variants: dict[str, Any] = dataclasses.field(default_factory=dict)
    grid: dict[str, Any] = dataclasses.field(default_factory=dict)
    samples: SampleSpec = dataclasses.field(default_factory=SampleSpec)
    keep_timeseries: KeepSpec = dataclasses.field(default_factory=KeepSpec)
    chunk_size: int = 0
    run_timeout_s: float | None = None

    def __post_init__(self) -> None:
        if not self.name or not all(c.isalnum() or c in "_-." for c in self.name):
            raise ConfigError(f"name must be non-empty and use only letters, digits, '_', '-', '.', got {self.name!r}")
        if isinstance(self.seeds, dict):
            object.__setattr__(self, "seeds", load_dataclass(SeedRange, self.seeds, "seeds"))
        elif isinstance(self.seeds, (list, tuple)):
            object.__setattr__(self, "seeds", tuple(_seed(f"seeds[{i}]", s) for i, s in enumerate(self.seeds)))
        elif not isinstance(self.seeds, SeedRange):
            raise ConfigError(f"seeds must be a list of seeds or {{start, count}}, got {self.seeds!r}")
        if isinstance(self.seeds, tuple):
            if not self.seeds:
                raise ConfigError("seeds must not be empty, got []")
            for i, s in enumerate(self.seeds):
                if s < 0:
                    raise ConfigError(f"seeds[{i}] must be >= 0, got {s!r}")
            if len(set(self.seeds)) != len(self.seeds):
                raise ConfigError(f"seeds must not repeat, got {list(self.seeds)!r}")
        for key, values in self.grid.items():
            if not isinstance(values, list) or not values:
                raise ConfigError(f"grid.{key} must be a non-empty list of values, got {values!r}")
        for vname, changes in self.variants.items():
            if not isinstance(vname, str) or not vname or not all(c.isalnum() or c in "_-." for c in vname):
                raise ConfigError(f"variants: name must be non-empty and use only letters, digits, '_', '-', '.', got {vname!r}")
            if not isinstance(changes, dict):
                raise ConfigError(f"variants.{vname} must be a mapping of dotted key -> value ({{}} for none), got {changes!r}")
            for key in changes:
                try:
                    check_scenario_key(key)
                except ConfigError as exc:
                    raise ConfigError(f"variants.{vname}.{key}: {exc}") from None
                if key in self.grid or key in self.samples.params:
                    raise ConfigError(f"variants.{vname}.{key} is also varied by grid or samples; vary a key in one place")
        if self.chunk_size < 0:
            raise ConfigError(f"chunk_size must be >= 0 (0 = automatic), got {self.chunk_size!r}")
        if self.run_timeout_s is not None:
            check_positive("run_timeout_s", self.run_timeout_s)
        for section, keys in (("overrides", self.overrides), ("grid", self.grid), ("samples.params", self.samples.params)):
            for key in keys:
                try:
                    check_scenario_key(key)
                except ConfigError as exc:
                    raise ConfigError(f"{section}.{key}: {exc}") from None
        clash = set(self.grid) & set(self.samples.params)
        if clash:
            raise ConfigError(f"grid and samples.params both vary {sorted(clash)[0]!r}; vary a key in one place")
        self._check_size()
        if self.samples.paired_with_seeds and len(self.seed_list()) != self.samples.count:
            raise ConfigError(
                f"samples.paired_with_seeds needs as many seeds as samples.count ({self.samples.count}), "
                f"got {len(self.seed_list())} seeds"
            )

    def n_runs(self) -> int:
        """How many runs the campaign has (variants x grid points x draws x seeds, or x 1 seed when paired)."""
        n_seeds = self.seeds.count if isinstance(self.seeds, SeedRange) else len(self.seeds)
        return ((len(self.variants) or 1) * math.prod(len(v) for v in self.grid.values()) * (self.samples.count or 1)
                * (1 if self.samples.paired_with_seeds else n_seeds))

    def _check_size(self) -> None:
        """Refuse, before any run is listed, a campaign whose list of runs and results would not fit in memory."""
        n_seeds = self.seeds.count if isinstance(self.seeds, SeedRange) else len(self.seeds)
        factors = {"seeds": 1 if self.samples.paired_with_seeds else n_seeds, "samples.count": self.samples.count or 1,
                   "grid": math.prod(len(v) for v in self.grid.values()), "variants": len(self.variants) or 1}
        key = max(factors, key=lambda k: factors[k])
        runs = self.n_runs()
        shown = f"{n_seeds} seeds" if key == "seeds" else f"{factors[key]} {'points' if key == 'grid' else key}"
        require_fits(key, f"{shown} ({runs:.3g} runs)", RUN_BYTES * runs,
                     what="the campaign's list of runs and their results", hint=f"fewer {key}, or several campaigns")

    def seed_list(self) -> tuple[int, ...]:
        """The seeds as a tuple."""
        if isinstance(self.seeds, SeedRange):
            return tuple(range(self.seeds.start, self.seeds.start + self.seeds.count))
        return self.seeds

    def varied_keys(self) -> tuple[str, ...]:
        """The columns that vary: ``variant`` (when there are variants), grid keys, then sampled keys."""
        return (("variant",) if self.variants else ()) + tuple(self.grid) + tuple(self.samples.params)

    def group_keys(self) -> tuple[str, ...]:
        """The columns that split the runs into summary groups: ``variant`` and the grid keys."""
        return (("variant",) if self.variants else ()) + tuple(self.grid)


#: What one run of a campaign holds in the engine before and after it runs: its point (a shallow copy of the
#: scenario mapping), its result row (metrics, counters) and its share of the results' table (bytes, rounded up).
RUN_BYTES = 16 * 1024


def _seed(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{name} must be an integer, got {value!r}")
    return value


def check_scenario_key(key: str) -> None:
    """Raise ConfigError unless ``key`` is a dotted path to a :class:`Scenario` field.

    Inside a ``dict`` field (``model.overrides``) any sub-key is accepted here;
    the scenario's own validation checks it when the run is built.  So is a key
    of a stage's section that its built-in kind does not have: the section may
    name another kind (``controller.kind: my_mod:MyController``), whose keys
    :func:`load_campaign_spec` checks against the scenario it gives.
    """
    if key in ("seed", "name"):
        raise ConfigError(f"is set by the campaign itself (use seeds / name), got key {key!r}")
    tp: Any = Scenario
    parts = key.split(".")
    for depth, part in enumerate(parts):
        if not dataclasses.is_dataclass(tp):
            origin = typing.get_origin(tp)
            if origin is dict or tp is dict:
                return
            raise ConfigError(f"{'.'.join(parts[:depth])} is a value, not a section (key {key!r})")
        hints = typing.get_type_hints(tp)
        fields = {f.name: f for f in dataclasses.fields(tp) if f.init}
        if part not in fields:
            where = ".".join(parts[:depth]) or "the scenario"
            raise ConfigError(f"unknown scenario key {key!r}: {where} has keys {sorted(fields)}")
        if RESOLVE_TYPE in fields[part].metadata and depth + 1 < len(parts):
            kind_fields = {f.name for f in dataclasses.fields(hints[part])}
            if parts[depth + 1] not in kind_fields:
                return  # a key of another kind's section: checked on the scenario (load_campaign_spec)
        tp = hints[part]
        # Optional[X] / X | None: follow X
        if typing.get_origin(tp) in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(args) == 1:
                tp = args[0]
    if dataclasses.is_dataclass(tp):
        raise ConfigError(f"names a section, not a value (key {key!r}); vary one of its keys")


@dataclasses.dataclass(frozen=True)
class RunPoint:
    """One run of a campaign before it is hashed.

    Attributes:
        index: Position in the campaign's run order.
        seed: Imager noise seed.
        values: Varied key -> value of this run (grid and sampled keys).
        mapping: The scenario mapping of the run (base + overrides + values + seed),
            not yet validated.
        keep_timeseries: Whether the run's time series is kept.
        group: Index of the run's variant x grid point (its mapping before the draws:
            :func:`group_mapping`).
        point: Index of the run's scenario without its seed (variant x grid point x draw);
            the runs of one point differ only in their seed.
        draw: The sampled key -> value of this run ({} without samples).
    """

    index: int
    seed: int
    values: dict[str, Any]
    mapping: dict[str, Any]
    keep_timeseries: bool
    group: int = 0
    point: int = 0
    draw: dict[str, Any] = dataclasses.field(default_factory=dict)


def expand_points(spec: CampaignSpec, base_mapping: dict[str, Any]) -> list[RunPoint]:
    """Every run of ``spec`` in order (grid x draws x seeds), see the module docstring.

    Args:
        spec: The campaign.
        base_mapping: The base scenario mapping with ``spec.overrides`` applied.
    """
    seeds = spec.seed_list()
    grid_points = [dict(zip(spec.grid, combo)) for combo in itertools.product(*spec.grid.values())]
    s = spec.samples
    if s.count:
        rng = np.random.default_rng(s.rng_seed)
        columns = {k: d.draw(rng, s.count) for k, d in s.params.items()}
        draws = [{k: float(columns[k][i]) for k in s.params} for i in range(s.count)]
    else:
        draws = [{}]
    keep_seeds, keep_runs = set(spec.keep_timeseries.seeds), set(spec.keep_timeseries.runs)
    variants: list[tuple[str | None, Any]] = list(spec.variants.items()) or [(None, {})]
    points: list[RunPoint] = []
    group = point = 0
    for vname, changes in variants:
        variant_base = overridden(base_mapping, changes)
        tag = {} if vname is None else {"variant": vname}
        for g in grid_points:
            for i, d in enumerate(draws):
                shared = overridden(variant_base, {**g, **d})  # the seeds of a point share its sections
                for seed in ((seeds[i],) if s.paired_with_seeds else seeds):
                    values = {**tag, **g, **d}
                    idx = len(points)
                    points.append(RunPoint(idx, seed, values, {**shared, "seed": seed},
                                           seed in keep_seeds or idx in keep_runs, group, point, d))
                point += 1
            group += 1
    return points


def group_mapping(spec: CampaignSpec, base_mapping: dict[str, Any], values: dict[str, Any]) -> dict[str, Any]:
    """The scenario mapping of a run's variant x grid point, before its draws and seed.

    Args:
        spec: The campaign.
        base_mapping: As for :func:`expand_points`.
        values: The run's :attr:`RunPoint.values` (``variant`` and the grid keys are read).
    """
    changes = spec.variants[values["variant"]] if spec.variants else {}
    return overridden(overridden(base_mapping, changes), {k: values[k] for k in spec.grid})


def campaign_spec_from_mapping(mapping: Any) -> CampaignSpec:
    """Build a :class:`CampaignSpec` from a plain mapping (strict)."""
    return load_dataclass(CampaignSpec, mapping, "")


def load_campaign_spec(path: str | Path) -> tuple[CampaignSpec, dict[str, Any]]:
    """Load a campaign file and its base scenario, and check them.

    Returns:
        ``(spec, base_mapping)``: the spec and the base scenario mapping with
        ``spec.overrides`` applied (a plain mapping, validated as a scenario).

    Raises:
        ConfigError: unknown or invalid key anywhere, a base scenario that does
            not validate, a grid value or a distribution centre that the scenario
            rejects (the message names the key and the value).
    """
    p = Path(path)
    spec = campaign_spec_from_mapping(load_yaml(p))
    base_path = Path(spec.base)
    if not base_path.is_absolute():
        base_path = p.parent / base_path
    try:
        base = load_scenario_mapping(base_path)  # the scenario file's own `base:` chain resolved, as every command
    except ConfigError as exc:
        raise ConfigError(f"base: {exc}") from None
    base = overridden(base, spec.overrides)
    try:
        scenario_from_mapping(base)
    except ConfigError as exc:
        raise ConfigError(f"base scenario {str(base_path)!r} with overrides: {exc}") from None
    for vname, changes in spec.variants.items():
        try:
            scenario_from_mapping(overridden(base, changes))
        except ConfigError as exc:
            raise ConfigError(f"variants.{vname} gives an invalid scenario: {exc}") from None
    for key, values in spec.grid.items():
        for i, v in enumerate(values):
            try:
                scenario_from_mapping(overridden(base, {key: v}))
            except ConfigError as exc:
                raise ConfigError(f"grid.{key}[{i}] = {v!r} gives an invalid scenario: {exc}") from None
    for key, dist in spec.samples.params.items():
        c = dist.centre()
        try:
            scenario_from_mapping(overridden(base, {key: c}))
        except ConfigError as exc:
            raise ConfigError(f"samples.params.{key}: value {c!r} (centre of the distribution) is rejected: {exc}") from None
    return spec, base
