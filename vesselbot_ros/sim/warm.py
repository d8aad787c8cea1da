"""Fill numba's on-disk cache: every compiled path a run uses, compiled (or loaded) once.

:mod:`vesselbot_ros.numba_cache` keeps that cache fresh (it runs on package
import); :func:`warm` fills it.  ``tools/bootstrap.sh`` calls it once per
version of the compiled sources, so ``make run``, ``make test`` and every node
start without compiling.  ``python -m vesselbot_ros.sim.warm [--no-progress]`` runs it
with a bar over the scenarios on a terminal.
"""

from __future__ import annotations

import argparse
import dataclasses as dc
from collections.abc import Iterable

import numpy as np

from vesselbot_ros.progress import ProgressFn, add_progress_argument, session, step, wanted
from vesselbot_ros.scanner.sequence import SequenceParams
from vesselbot_ros.sim.closed_loop import run_closed_loop, run_many
from vesselbot_ros.sim.scenario import (
    DEFAULT_SCENARIO,
    MR_IMAGES_PLAN,
    Scenario,
    load_scenario,
    scenario_with,
    shipped_scenarios,
    short_copy,
)
from vesselbot_ros.vessels.network import load_network
from vesselbot_ros.vessels.tree_field import check_build, meshed_wall

__all__ = ["warm", "main"]


#: What :func:`warm` compiles: ``all`` (every shipped scenario: what ``make test`` needs, the 3-D trees' wall
#: lookups included, minutes on a fresh machine), its parts ``planar``, ``trees`` (the 3-D scenarios) and
#: ``wall_build`` (the wall's build, :func:`warm_wall_build`), which the bootstrap warms in three processes at once,
#: or ``run`` (the default scenario: what ``make run`` needs; the rest compiles on first use, a 3-D wall build
#: saying so in one line).  Where a shipped tree's wall lookup is not yet in the machine's cache, ``trees`` builds
#: it, and compiles the wall's build first itself (``wall_build`` then does nothing: one compile, not two at once).
SCOPES = ("all", "planar", "trees", "wall_build", "run")


def walls_cached(scenarios: Iterable[Scenario] | None = None) -> bool:
    """Whether the wall lookup of every 3-D tree of ``scenarios`` (default: the shipped ones), for its scenarios'
    blood, is in the machine's cache, so that no warm-up of the trees builds one."""
    if scenarios is None:
        scenarios = [load_scenario(path) for path in shipped_scenarios().values()]
    pairs = {(sc.physics.vessel.network, sc.physics.blood) for sc in scenarios if sc.dims == 3}
    return all(check_build(load_network(net), blood, quiet=True) is None for net, blood in pairs)


def _in_scope(scope: str, name: str, dims: int) -> bool:
    return (scope == "all" or (scope == "planar" and dims == 2) or (scope == "trees" and dims == 3)
            or (scope == "run" and name == DEFAULT_SCENARIO))  # wall_build: no scenario


def warm_wall_build() -> None:
    """Compile the 3-D wall's build (:func:`~vesselbot_ros.geometry.field_build.build_wall_field3d` at the plant's
    settings, its candidate tree included) on a block of the reference Y (seconds once compiled): what a new tree's
    first run and the cross-kernel build test (test_builds_fingerprint: a subprocess per kernel) would otherwise
    each compile, minutes; the shipped trees' fields may already be in the machine's cache, so their builds may
    not run here."""
    # deferred: gmsh's Y is heavy, and only this part of the warm-up needs it
    from vesselbot_ros.geometry.fixtures import y_wall
    from vesselbot_ros.vessels.tree_field import build_plant_field, plant_wall3d

    h = 0.25e-3
    v, t, caps, _n = y_wall(0.2e-3)
    build_plant_field(plant_wall3d(v, t, caps, h), h, np.array([-1.0e-3, -1.5e-3, -1.0e-3]), (10, 10, 10))


def warm(progress: ProgressFn | None = None, *, scope: str = "all") -> None:
    """Compile (or load) every compiled path a run uses: both loops of each shipped scenario (``scope="all"``) or
    of the default scenario (``scope="run"``, :data:`SCOPES`), briefly.

    ``progress(done, total)`` is called after each scenario warmed (default: :func:`~vesselbot_ros.progress.step`'s,
    a bar when a command draws them).
    """
    if scope not in SCOPES:
        raise ValueError(f"scope must be one of {SCOPES}, got {scope!r}")
    if progress is None:
        with step("numba warm-up") as report:
            warm(report, scope=scope)
        return
    loaded = [(name, load_scenario(path)) for name, path in shipped_scenarios().items()]
    scenarios = [sc for name, sc in loaded if _in_scope(scope, name, sc.dims)]
    planar = next((sc for sc in scenarios if sc.dims == 2), None)
    if planar is not None:
        # the scanner's stages as the nodes and the per-tick loop call them, even if no shipped scenario multiplexes
        scenarios.append(dc.replace(planar, sequence=SequenceParams(mode="multiplexed", tracking_window_s=0.002,
                                                                    dead_time_s=0.001, propulsion_window_s=0.003,
                                                                    latency_s=0.001)))
    progress(0, len(scenarios))
    if scope == "all":
        warm_wall_build()
    elif scope in ("trees", "wall_build"):
        # the 3-D part compiles it before it builds a missing lookup, else the wall build's own part does
        owner = "wall_build" if walls_cached(sc for _name, sc in loaded) else "trees"
        if scope == owner:
            warm_wall_build()
    if scope in ("all", "planar"):  # the MR-image stages (no shipped scenario runs them; they run per tick)
        path, changes = MR_IMAGES_PLAN
        run_closed_loop(scenario_with(load_scenario(path), {**changes, "sim.duration_s": 0.06}), path="per_tick")
    for done, sc in enumerate(scenarios, 1):
        sc = short_copy(sc, 0.01)  # a multiplexed sequence shrunk to fit the 10 ticks (the same compiled code)
        run_closed_loop(sc)  # the compiled loop (every built-in stage)
        run_closed_loop(sc, path="per_tick")  # the stage classes, each calling its compiled function
        run_many(sc, [0, 1], workers=2)
        if sc.physics.vessel.network:  # the nodes' input check (VesselbotNode.check); a tree's lookup is built above
            meshed_wall(load_network(sc.physics.vessel.network), sc.physics.blood).clearance(*([0.0] * sc.dims))
        progress(done, len(scenarios))


def main(argv: list[str] | None = None) -> int:
    """``python -m vesselbot_ros.sim.warm [--no-progress]``: :func:`warm`, with a bar on a terminal."""
    parser = argparse.ArgumentParser(prog="python -m vesselbot_ros.sim.warm",
                                     description="fill numba's on-disk cache (every compiled path a run uses)")
    parser.add_argument("--scope", choices=SCOPES, default="all",
                        help="all: every shipped scenario (make test), or its parts planar, trees (3-D) and wall_build "
                             "(the 3-D wall's build); run: the default scenario (make run)")
    add_progress_argument(parser)
    args = parser.parse_args(argv)
    with session(wanted(args.no_progress)):
        warm(scope=args.scope)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
