"""Planning and comparison of `replay --into` (no ROS graph: bags written in the test)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.errors import BagError
from vesselbot_ros.launch.reestimate import (
    ROLES,
    compare_outputs,
    node_command,
    output_values,
    plan_feed,
    replay_topic,
)

DT = 1e-3
N = 40


def _config(duration_s: float = N * DT) -> dict:
    from vesselbot_ros.sim.scenario import Scenario

    cfg = Scenario().to_mapping()
    cfg["sim"]["duration_s"] = duration_s
    cfg["sim"]["control_rate_Hz"] = 1.0 / DT
    cfg["seed"] = 11
    return cfg


def _stamp(header, ns: int, frame: str = "vessel") -> None:
    header.stamp.sec, header.stamp.nanosec = divmod(ns, 1_000_000_000)
    header.frame_id = frame


def _write(path: Path, *, mode: str = "lockstep", config: dict | None = None, skip_applied: int | None = None,
           frame_every: int = 1, duplicate_applied: int | None = None) -> Path:
    """A lockstep-like bag of N ticks whose values are closed-form functions of k.

    measurement n: stamp = acquisition tick (n // frame_every) * frame_every, point = (k_acq, 0, -k_acq) um;
    coil/applied k: (1e-3 k, 0, -2e-3 k) T/m; estimate k: position (2k, 0, 3k) um, twist (k, 0, -k) mm/s;
    reference k: position (5k) um; gradient_command k: (4e-3 k, 0, 1e-3) T/m.  Per tick the log order is
    clock, measurement, estimate, reference, command, applied (as the graph publishes them).
    """
    from geometry_msgs.msg import PointStamped, Vector3Stamped
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from vesselbot_msgs.msg import ReferenceSample

    from vesselbot_ros.bag.writer import BagWriter
    from vesselbot_ros.graph_spec import topic

    meta = {"scenario": "unit", "seed": 11, "mode": mode, "config": _config() if config is None else config}
    with BagWriter(path, run_metadata=meta) as bag:
        conns = {k: bag.add_topic(topic(k).name, topic(k).msgtype) for k in
                 ("clock", "measurement", "estimate", "reference", "gradient_command", "coil_applied")}
        t0 = 5_000_000_000
        for k in range(N):
            ns = int(round(k * DT * 1e9))
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(ns, 1_000_000_000)
            me = PointStamped()
            k_acq = (k // frame_every) * frame_every
            _stamp(me.header, int(round(k_acq * DT * 1e9)))
            me.point.x, me.point.z = k_acq * 1e-6, -k_acq * 1e-6
            es = Odometry()
            _stamp(es.header, ns)
            es.pose.pose.position.x, es.pose.pose.position.z = 2e-6 * k, 3e-6 * k
            es.twist.twist.linear.x, es.twist.twist.linear.z = 1e-3 * k, -1e-3 * k
            es.pose.covariance[35] = 0.5 * k
            rf = ReferenceSample()
            _stamp(rf.header, ns)
            rf.tick = k
            rf.position.x = 5e-6 * k
            cmd = Vector3Stamped()
            _stamp(cmd.header, ns)
            cmd.vector.x, cmd.vector.z = 4e-3 * k, 1e-3
            ap = Vector3Stamped()
            _stamp(ap.header, ns)
            ap.vector.x, ap.vector.z = 1e-3 * k, -2e-3 * k
            msgs = [("clock", c), ("measurement", me), ("estimate", es), ("reference", rf),
                    ("gradient_command", cmd)]
            if k != skip_applied:
                msgs.append(("coil_applied", ap))
            if k == duplicate_applied:
                ap2 = Vector3Stamped()
                _stamp(ap2.header, ns)
                ap2.vector.x = 99.0
                msgs.append(("coil_applied", ap2))
            for j, (key, msg) in enumerate(msgs):
                bag.write(conns[key], serialize_message(msg), t0 + k * 1_000_000 + j * 1000)
    return path


def _decode(rec):
    from vesselbot_ros.bag.writer import make_typestore

    return make_typestore().deserialize_cdr(rec.data, rec.msgtype)


def test_observer_plan_feeds_applied_k_minus_1_then_measurement_k_with_the_recorded_estimate(tmp_path):
    plan = plan_feed(_write(tmp_path / "b"), "observer")
    assert plan.role == "observer" and plan.n_ticks == N and plan.dt_s == DT and plan.stop_reason == ""
    assert [t.k for t in plan.ticks] == list(range(N))
    assert plan.run_metadata["seed"] == 11
    t0 = plan.ticks[0]
    assert [r.topic for r in t0.inputs] == ["/vesselbot/measurement"]  # k = 0: no applied gradient yet
    for t in plan.ticks[1:]:
        assert [r.topic for r in t.inputs] == ["/vesselbot/coil/applied", "/vesselbot/measurement"]
        applied, meas = (_decode(r) for r in t.inputs)
        assert applied.vector.x == 1e-3 * (t.k - 1) and applied.vector.z == -2e-3 * (t.k - 1)
        assert meas.point.x == t.k * 1e-6
        est = _decode(t.recorded_output)
        assert est.pose.pose.position.x == 2e-6 * t.k
        assert _decode(t.clock).clock.nanosec == int(round(t.k * DT * 1e9))


def test_controller_plan_feeds_reference_and_estimate_of_tick_k(tmp_path):
    plan = plan_feed(_write(tmp_path / "b"), "controller")
    assert len(plan.ticks) == N
    for t in plan.ticks:
        assert [r.topic for r in t.inputs] == ["/vesselbot/reference", "/vesselbot/estimate"]
        ref, est = (_decode(r) for r in t.inputs)
        assert ref.tick == t.k and est.pose.pose.position.z == 3e-6 * t.k
        assert _decode(t.recorded_output).vector.x == 4e-3 * t.k


def test_measurements_belong_to_ticks_by_order_even_when_the_frame_is_held(tmp_path):
    # a 250 Hz imager at 1 kHz control: the frame of tick 4j is repeated (same stamp) on ticks 4j+1..4j+3
    plan = plan_feed(_write(tmp_path / "b", frame_every=4), "observer")
    assert len(plan.ticks) == N
    for t in plan.ticks:
        meas = _decode(t.inputs[-1])
        assert meas.point.x == (t.k // 4) * 4 * 1e-6, t.k


def test_plan_stops_at_the_first_tick_with_a_missing_input(tmp_path):
    plan = plan_feed(_write(tmp_path / "b", skip_applied=20), "observer")
    # the observer's tick 21 needs coil/applied of tick 20
    assert [t.k for t in plan.ticks] == list(range(21))
    assert "/vesselbot/coil/applied for tick 20" in plan.stop_reason
    assert plan.warnings == (f"the bag holds {N - 1} /vesselbot/coil/applied messages for {N} ticks: the recording "
                             f"lost some or the run ended early",)
    assert plan_feed(tmp_path / "b", "observer").warnings and not plan_feed(_write(tmp_path / "c"), "observer").warnings
    # the controller does not need coil/applied
    assert len(plan_feed(tmp_path / "b", "controller").ticks) == N


def test_first_message_of_a_tick_wins_as_in_the_live_node(tmp_path):
    plan = plan_feed(_write(tmp_path / "b", duplicate_applied=7), "observer")
    assert _decode(plan.ticks[8].inputs[0]).vector.x == 1e-3 * 7


def test_plan_needs_a_lockstep_bag_with_its_config(tmp_path):
    with pytest.raises(BagError, match="recorded in mode 'realtime'; --into needs a lockstep run"):
        plan_feed(_write(tmp_path / "rt", mode="realtime"), "observer")
    from vesselbot_ros.bag.writer import BagWriter

    with BagWriter(tmp_path / "bare", run_metadata={"scenario": "x"}) as bag:
        bag.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    with pytest.raises(BagError, match=r"has no run config \(custom_data 'vesselbot.run'\)"):
        plan_feed(tmp_path / "bare", "observer")
    with pytest.raises(BagError, match="--into must be one of"):
        plan_feed(tmp_path / "rt", "plant")


def test_plan_rejects_an_invalid_recorded_config(tmp_path):
    from vesselbot_ros.config import ConfigError

    cfg = _config()
    cfg["imager"]["noise_sigma_m"] = -1.0
    with pytest.raises(ConfigError, match="noise_sigma_m"):
        plan_feed(_write(tmp_path / "b", config=cfg), "observer")


def test_compare_outputs_by_hand():
    rec = {0: np.array([1.0, 2.0, 3.0]), 1: np.array([1.0, 2.0, math.nan]), 2: np.array([0.0, 0.0, 0.0])}
    new = {0: np.array([1.0, 2.0, 3.0]), 1: np.array([1.5, 2.0, math.nan]), 2: np.array([0.0, -0.25, 0.0]),
           3: np.array([9.0, 9.0, 9.0])}
    c = compare_outputs("controller", rec, new)
    assert c.compared == 3 and c.identical == 1 and c.missing_recorded == 1
    assert c.first_difference_tick == 1
    assert c.max_abs == {"u_x_T_per_m": 0.5, "u_y_T_per_m": 0.25, "u_z_T_per_m": 0.0}
    assert c.max_abs_overall == 0.5
    # NaN on one side only is an infinite difference
    c2 = compare_outputs("controller", {0: np.array([0.0, 0.0, 0.0])}, {0: np.array([math.nan, 0.0, 0.0])})
    assert c2.max_abs["u_x_T_per_m"] == math.inf and c2.identical == 0
    same = compare_outputs("observer", {5: np.arange(7.0)}, {5: np.arange(7.0)})
    assert same.identical == 1 and same.max_abs_overall == 0.0 and same.first_difference_tick is None


def test_output_values_follow_the_field_order():
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry

    o = Odometry()
    o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.position.z = 1.0, 2.0, 3.0
    o.twist.twist.linear.x, o.twist.twist.linear.y, o.twist.twist.linear.z = 4.0, 5.0, 6.0
    o.pose.covariance[35] = 7.0
    assert output_values("observer", o).tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    assert len(ROLES["observer"].fields) == 7
    v = Vector3Stamped()
    v.vector.x, v.vector.y, v.vector.z = 0.1, 0.0, -0.2
    assert output_values("controller", v).tolist() == [0.1, 0.0, -0.2]
    assert replay_topic("observer") == "/vesselbot/replay/estimate"
    assert replay_topic("controller") == "/vesselbot/replay/gradient_command"


def test_node_command_default_custom_and_params_placeholder(tmp_path):
    pf = tmp_path / "params.yaml"
    assert node_command("observer", None, pf) == [sys.executable, "-m", "vesselbot_ros.nodes.observer_node",
                                                  "--ros-args", "--params-file", str(pf)]
    assert node_command("controller", "python my_ctrl.py --gain 2", pf) == [
        sys.executable, "my_ctrl.py", "--gain", "2", "--ros-args", "--params-file", str(pf)]
    assert node_command("observer", "./obs --config={params} -v", pf) == ["./obs", f"--config={pf}", "-v"]
    assert node_command("observer", ["obs", "a b"], pf)[:2] == ["obs", "a b"]
    with pytest.raises(BagError, match="--node-cmd is empty"):
        node_command("observer", "  ", pf)
