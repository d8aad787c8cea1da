"""The environments' warm-up: each tier's default scenario stepped in both environments, by scope."""

from __future__ import annotations

import pytest

from vesselbot_ros.envs import warm as envs_warm
from vesselbot_ros.envs.registration import TIERS
from vesselbot_ros.sim.scenario import load_scenario


def test_the_scopes_split_the_tiers_into_the_plane_and_the_trees(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    stepped: list[str] = []

    class Env:
        def __init__(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
            self.scenario = args[-1]
            self.action_space = type("S", (), {"shape": (2,)})()

        def reset(self, seed: int) -> None:
            stepped.append(self.scenario.name)

        def step(self, action) -> None:  # type: ignore[no-untyped-def]
            pass

        def close(self) -> None:
            pass

    monkeypatch.setattr(envs_warm, "VesselbotEnv", Env)
    monkeypatch.setattr(envs_warm, "VesselbotVectorEnv", Env)
    dims = {name: load_scenario(name).dims for name in TIERS.values()}
    for scope, want in (("planar", 2), ("trees", 3)):
        stepped.clear()
        envs_warm.warm(ticks=1, scope=scope)
        assert sorted(set(stepped)) == sorted(n for n, d in dims.items() if d == want)
    stepped.clear()
    envs_warm.warm(ticks=1)
    assert sorted(set(stepped)) == sorted(TIERS.values())
    with pytest.raises(ValueError, match="scope"):
        envs_warm.warm(scope="everything")


def test_the_plane_warms_for_real() -> None:
    assert envs_warm.main(["--scope", "planar", "--no-progress"]) == 0
