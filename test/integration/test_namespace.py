"""Two graphs on one ROS domain, in different namespaces, do not cross.

Lockstep makes crosstalk loud: a plant answered by the other graph's coil driver, or an observer
fed the other imager's frames, would change the numbers, double the per-tick counts in the bags
(and fail the published-vs-recorded check).  Both runs must instead reproduce the pure runner
bit for bit with exactly one message per tick on every per-tick topic.
"""

from __future__ import annotations

import json
import subprocess

import pytest

pytest.importorskip("rclpy")

from _runs import REPO, run_cmd
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

CONFIG = REPO / "config" / "sound_small_artery.yaml"
DURATION = 0.2


@pytest.mark.timeout(300)
def test_two_namespaced_graphs_on_one_domain_do_not_cross(tmp_path, peer_domain):
    from vesselbot_ros.bag.reader import open_bag
    from vesselbot_ros.graph_spec import TOPICS

    dom = peer_domain
    runs = {}
    for ns, seed in ((None, 1), ("robot2", 2)):
        label = ns or "default"
        args = ["--config", str(CONFIG), "--duration", str(DURATION), "--seed", str(seed), "--domain-id", str(dom),
                "--record-dir", str(tmp_path / label), "--metrics-json", str(tmp_path / f"{label}.json"), "--quiet"]
        if ns:
            args += ["--namespace", ns]
        runs[label] = subprocess.Popen(run_cmd(*args), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                       text=True)
    outs = {label: p.communicate(timeout=240) for label, p in runs.items()}
    for label, p in runs.items():
        assert p.returncode == 0, (label, outs[label])
    n = int(round(DURATION * 1000))
    for label, seed in (("default", 1), ("robot2", 2)):
        pure = run_closed_loop(load_scenario(CONFIG, duration=DURATION, seed=seed))
        ros = json.loads((tmp_path / f"{label}.json").read_text())
        for key in ("p_true", "x_hat", "g_applied"):
            assert ros["final"][key] == [float(x) for x in pure.timeseries[key][-1]], (label, key)
        info = open_bag(tmp_path / label)
        assert info.consistent, info.problems
        for t in TOPICS:
            if t.per_tick:
                assert info.topic(t.name).count == n, (label, t.name, info.topic(t.name).count)
        assert info.run_metadata["namespace"] == ("/robot2" if label == "robot2" else "/vesselbot")
    # different seeds: the imager noise differs, so the two graphs really ran apart
    a = json.loads((tmp_path / "default.json").read_text())["final"]["x_hat"]
    b = json.loads((tmp_path / "robot2.json").read_text())["final"]["x_hat"]
    assert a != b
