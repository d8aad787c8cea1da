"""Fill numba's on-disk cache: every compiled path a run uses, compiled (or loaded) once.

:mod:`vesselbot_ros.numba_cache` keeps that cache fresh (it runs on package
import); :func:`warm` fills it.  ``tools/bootstrap.sh`` calls it once per
version of the compiled sources, so ``make run``, ``make test`` and every node
start without compiling.
"""

from __future__ import annotations

import dataclasses as dc

from vesselbot_ros.scanner.sequence import SequenceParams
from vesselbot_ros.sim.closed_loop import run_closed_loop, run_many
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios, short_copy
from vesselbot_ros.vessels.cfd import network_wall
from vesselbot_ros.vessels.network import load_network

__all__ = ["warm"]


def warm() -> None:
    """Compile (or load) every compiled path a run uses: both loops of each shipped scenario, briefly."""
    scenarios = [load_scenario(path) for path in shipped_scenarios().values()]
    planar = next(sc for sc in scenarios if sc.dims == 2)
    # the scanner's stages as the nodes and the per-tick loop call them, even if no shipped scenario multiplexes
    scenarios.append(dc.replace(planar, sequence=SequenceParams(mode="multiplexed", tracking_window_s=0.002,
                                                                      dead_time_s=0.001, propulsion_window_s=0.003,
                                                                      latency_s=0.001)))
    for sc in scenarios:
        sc = short_copy(sc, 0.01)  # a multiplexed sequence shrunk to fit the 10 ticks (the same compiled code)
        run_closed_loop(sc)  # the compiled loop (every built-in stage)
        run_closed_loop(sc, path="per_tick")  # the stage classes, each calling its compiled function
        run_many(sc, [0, 1], workers=2)
        if sc.physics.vessel.network and sc.dims == 2:  # the nodes' input check (VesselbotNode.check)
            network_wall(load_network(sc.physics.vessel.network), sc.physics.blood).clearance(0.0, 0.0)
        # a 3-D tree's run above built (or read) its wall lookup and cached it: the nodes and tests read it
