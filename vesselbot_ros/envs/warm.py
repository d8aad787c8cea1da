"""Fill numba's on-disk cache with the environments' kernel, as :mod:`vesselbot_ros.sim.warm` does for the loops.

``python -m vesselbot_ros.envs.warm`` steps one scalar and one vector environment of each tier's default scenario
(:data:`~vesselbot_ros.envs.registration.TIERS`: the plane, a network, a 3-D tree, a multiplexed sequence) a few
ticks, so that the first ``gymnasium.make("vesselbot/...")`` of a session loads the kernel instead of compiling it
(about half a minute per kind of scenario).  ``tools/bootstrap.sh`` runs it with ``--loops`` (the loops' warm-up of
the same half first, which builds a 3-D tree's wall lookup), in the background.
"""

from __future__ import annotations

import argparse

import numpy as np

from vesselbot_ros.progress import add_progress_argument, session, step, wanted
from vesselbot_ros.sim import warm as sim_warm
from vesselbot_ros.sim.scenario import load_scenario

from .env import VesselbotEnv
from .registration import TIERS
from .vector import VesselbotVectorEnv

__all__ = ["warm", "main"]


#: ``all`` tiers, or the parts the bootstrap's planar and 3-D warm-up processes take after their loops: ``planar`` (the
#: plane's tiers) and ``trees`` (a 3-D tree's, after that process built its wall lookups).
SCOPES = ("all", "planar", "trees")


def warm(ticks: int = 3, scope: str = "all") -> None:
    """Step each tier's default scenario (of ``scope``, :data:`SCOPES`) ``ticks`` times in a scalar and a two-copy
    vector environment."""
    if scope not in SCOPES:
        raise ValueError(f"scope must be one of {SCOPES}, got {scope!r}")
    scenarios = [load_scenario(name) for name in TIERS.values()]
    scenarios = [sc for sc in scenarios if scope == "all" or (sc.dims == 3) == (scope == "trees")]
    with step("numba warm-up (environments)") as report:
        report(0, len(scenarios))
        for done, scenario in enumerate(scenarios, 1):
            env = VesselbotEnv(scenario)
            env.reset(seed=0)
            vec = VesselbotVectorEnv(2, scenario)
            vec.reset(seed=0)
            for _ in range(ticks):
                env.step(np.zeros(env.action_space.shape))
                vec.step(np.zeros(vec.action_space.shape))
            vec.close()
            report(done, len(scenarios))


def main(argv: list[str] | None = None) -> int:
    """``python -m vesselbot_ros.envs.warm [--no-progress]``: :func:`warm`."""
    parser = argparse.ArgumentParser(prog="python -m vesselbot_ros.envs.warm",
                                     description="fill numba's on-disk cache with the environments' kernel")
    parser.add_argument("--scope", choices=SCOPES, default="all",
                        help="all tiers, or the plane's (planar) or a 3-D tree's (trees)")
    parser.add_argument("--loops", action="store_true",
                        help="first the closed loops of the same scope (python -m vesselbot_ros.sim.warm)")
    add_progress_argument(parser)
    args = parser.parse_args(argv)
    with session(wanted(args.no_progress)):
        if args.loops:
            sim_warm.warm(scope=args.scope)
        warm(scope=args.scope)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
