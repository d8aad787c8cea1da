"""The imager's InjectFault service over real topics: a stand-alone imager node, driven tick by tick.

A probe node plays the plant: it publishes ``truth`` ticks (lockstep, 1 kHz, robot at rest at
P_TRUE), waits for each tick's ``measurement``, and calls ``/vesselbot/imager/inject_fault``.
The imager runs at 1 kHz frames with 1 um noise, so a 1 mm outlier is unmistakable and a held
(dropped-out) frame is recognisable by its unchanged acquisition stamp and value.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from _runs import start_node, status_values, truth_msg  # noqa: E402

DT_S = 1e-3
NOISE_M = 1e-6
P_TRUE = (2.0e-3, 0.2e-3)
BURST_TICKS = (20, 25)  # injected "now" before tick 20, 5 ms
DROP_TICKS = (35, 40)  # injected for 35 ms .. 40 ms
MAG_M = 1e-3


@pytest.fixture(scope="module")
def imager_session(tmp_path_factory):
    """Run the scripted session once; return what the probe saw."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PointStamped
    from rclpy.executors import SingleThreadedExecutor
    from vesselbot_msgs.msg import PlantState
    from vesselbot_msgs.srv import InjectFault

    from vesselbot_ros.graph_spec import qos_profile, topic
    from vesselbot_ros.testing import call_service, isolated_ros, spin_until

    tmp = tmp_path_factory.mktemp("imager_srv")
    with isolated_ros(tmp) as ros:
        proc = start_node("imager", ros.env, tmp / "imager.log", imager__frame_rate_Hz=1000.0,
                          imager__noise_sigma_m=NOISE_M)
        node = rclpy.create_node("imager_probe", context=ros.context)
        ex = SingleThreadedExecutor(context=ros.context)
        ex.add_node(node)
        try:
            pub = node.create_publisher(PlantState, topic("truth").name, qos_profile(topic("truth")))
            meas: list[PointStamped] = []
            diags: list[tuple[dict[str, str], int]] = []
            node.create_subscription(PointStamped, topic("measurement").name, meas.append,
                                     qos_profile(topic("measurement")))
            node.create_subscription(DiagnosticArray, "/diagnostics",
                                     lambda m: diags.extend(status_values(m, "vesselbot_imager")),
                                     qos_profile(topic("diagnostics")))
            cli = node.create_client(InjectFault, "/vesselbot/imager/inject_fault")
            assert spin_until(ex, lambda: pub.get_subscription_count() > 0 and cli.service_is_ready()
                              and any(d.get("wired") == "true" for d, _ in diags), timeout=60), proc.output()

            def tick(k: int) -> None:
                pub.publish(truth_msg(k, DT_S, P_TRUE))
                assert spin_until(ex, lambda: len(meas) == k + 1, timeout=10), (k, proc.output())

            def call(kind: int, start: float, duration: float, magnitude: float) -> object:
                answer = call_service(ex, cli, InjectFault.Request(kind=kind, start_time=start, duration=duration,
                                                                   magnitude=magnitude), 10, idempotent=False)
                assert answer is not None
                return answer

            # the client's first call: a refused fault, harmless if sent twice (a fresh client's answer can be lost)
            assert not call_service(ex, cli, InjectFault.Request(kind=7, start_time=0.0, duration=0.01), 10).accepted

            for k in range(BURST_TICKS[0]):
                tick(k)
            responses = {"burst": call(InjectFault.Request.OUTLIER_BURST, -1.0, 0.005, MAG_M)}
            for k in range(BURST_TICKS[0], 30):
                tick(k)
            responses["dropout"] = call(InjectFault.Request.DROPOUT, 0.035, 0.005, 0.0)
            responses["bad"] = call(InjectFault.Request.DROPOUT, 0.05, -0.01, 0.0)
            responses["bad_kind"] = call(7, 0.05, 0.01, 0.0)
            for k in range(30, 45):
                tick(k)
            n_before = len(diags)
            assert spin_until(ex, lambda: len(diags) > n_before, timeout=5)  # diagnostics after the last tick
            alive = proc.alive()
        finally:
            node.destroy_node()
            code = proc.stop()
    return {"meas": meas, "diags": diags, "responses": responses, "alive": alive, "exit": code}


@pytest.mark.timeout(120)
def test_outlier_burst_offsets_exactly_its_frames(imager_session):
    r = imager_session["responses"]["burst"]
    assert r.accepted, r.message
    assert r.effective_start_time == pytest.approx(BURST_TICKS[0] * DT_S, abs=1e-12)  # "now" = the next tick
    meas = imager_session["meas"]
    p = np.array([[m.point.x, m.point.z] for m in meas])
    err = np.linalg.norm(p - np.asarray(P_TRUE), axis=1)
    a, b = BURST_TICKS
    # inside the burst: offset by the magnitude (noise 1 um); outside: noise only
    np.testing.assert_allclose(err[a:b], MAG_M, atol=10 * NOISE_M)
    assert np.all(err[:a] < 10 * NOISE_M) and np.all(err[b:DROP_TICKS[0]] < 10 * NOISE_M)
    assert all(m.point.y == 0.0 and m.header.frame_id == "vessel" for m in meas)


@pytest.mark.timeout(120)
def test_dropout_holds_the_last_frame(imager_session):
    r = imager_session["responses"]["dropout"]
    assert r.accepted and r.effective_start_time == pytest.approx(0.035)
    meas = imager_session["meas"]
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in meas]
    a, b = DROP_TICKS
    held = meas[a - 1]
    assert stamps[a - 1] == round((a - 1) * DT_S * 1e9)
    for k in range(a, b):  # zero-order hold: the last frame again, same stamp, same value
        assert stamps[k] == stamps[a - 1]
        assert (meas[k].point.x, meas[k].point.z) == (held.point.x, held.point.z)
    for k in range(b, len(meas)):  # fresh frames again, one per tick
        assert stamps[k] == round(k * DT_S * 1e9)
    assert len(meas) == 45


@pytest.mark.timeout(120)
def test_invalid_requests_are_refused_and_the_node_keeps_running(imager_session):
    bad = imager_session["responses"]["bad"]
    assert not bad.accepted and "duration_s" in bad.message and "-0.01" in bad.message
    bad_kind = imager_session["responses"]["bad_kind"]
    assert not bad_kind.accepted and "got 7" in bad_kind.message
    assert imager_session["alive"]
    assert imager_session["exit"] == 0


@pytest.mark.timeout(120)
def test_faults_are_announced_on_diagnostics(imager_session):
    diags = [d for d, _ in imager_session["diags"]]
    announced = {(d["fault_kind"], float(d["fault_start"]), float(d["fault_duration"]), d["fault_source"])
                 for d in diags if "fault_kind" in d}
    assert announced == {("outlier_burst", 0.02, 0.005, "service"), ("dropout", 0.035, 0.005, "service")}
    burst = next(d for d in diags if d.get("fault_kind") == "outlier_burst")
    assert math.isclose(float(burst["fault_magnitude"]), MAG_M)
    last = diags[-1]
    assert last["outlier_frames"] == "5" and last["dropout_frames"] == "5"
    assert last["faults_announced"] == "2"  # refused requests are not announced
    assert last["frames"] == "40"  # 45 ticks, 5 dropped
