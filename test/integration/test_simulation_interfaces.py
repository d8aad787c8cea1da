"""A run driven through the ``simulation_interfaces`` services and action alone (``vesselbot run --start-paused``).

Start paused, step 100 ticks (the bag then holds exactly 100 ticks), reset,
step in pieces (a service call and an action goal with feedback), then play
to the end.  The ticks after the reset equal an unpaused run message for
message, and so do the 100 before it.
"""

from __future__ import annotations

import json
import subprocess
import time

import pytest

from _runs import run_cmd
from vesselbot_ros.graph_spec import TOPICS, import_type, resolve, service
from vesselbot_ros.testing import call_service, spin_until

DURATION = 0.3
N = int(round(DURATION * 1000))
PER_TICK = [t for t in TOPICS if t.per_tick]


def _call(ex, client, request, timeout=120.0, idempotent=True):
    """One answered call; ``idempotent=False`` for a request that must run once (the client answered before)."""
    assert client.wait_for_service(timeout_sec=timeout), client.srv_name
    answer = call_service(ex, client, request, timeout, idempotent=idempotent)
    assert answer is not None, f"{client.srv_name}: no answer within {timeout} s"
    return answer


def _per_tick_messages(bag):
    """Topic -> decoded messages (rclpy classes, compared by value), in bag order."""
    from rclpy.serialization import deserialize_message

    from vesselbot_ros.bag.reader import iter_messages, open_bag

    out = {t.name: [] for t in PER_TICK}
    types = {t.name: import_type(t.msgtype) for t in PER_TICK}
    for m in iter_messages(open_bag(bag), topics=list(out)):
        out[m.topic].append(deserialize_message(m.data, types[m.topic]))
    return out


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("composed", [[], ["--single-process"]], ids=["processes", "single_process"])
def test_paused_stepped_reset_and_played_run_equals_an_unpaused_run(tmp_path, composed, peer_domain):
    """Driven run: one process per node, or composed (steps then arrive from the services' thread)."""
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.executors import SingleThreadedExecutor
    from simulation_interfaces.msg import Result, SimulationState, SimulatorFeatures
    from simulation_interfaces.srv import ResetSimulation, SetSimulationState, StepSimulation
    from std_srvs.srv import Trigger

    from vesselbot_ros.ros_env import apply_to_process, restore_process_env, ros_environment

    dom = peer_domain
    common = ["--config", "sound_small_artery", "--duration", str(DURATION), "--seed", "3", "--quiet"]
    driven = subprocess.Popen(run_cmd(*common, *composed, "--start-paused", "--domain-id", str(dom),
                                      "--record-dir", str(tmp_path / "driven")),
                              cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    saved = apply_to_process(ros_environment(dom, tmp_path / "client_log"))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    node = rclpy.create_node("simulation_client", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)

    def client(key):
        s = service(key)
        return node.create_client(import_type(s.srvtype), resolve(s.rel))

    try:
        # a fresh client's first call is one that may run twice (a loaded machine can drop its answer:
        # vesselbot_ros.nodes.calls); the calls that must run once come after the client's first answer
        first = client("get_simulator_features")
        deadline = time.monotonic() + 120
        while not first.wait_for_service(timeout_sec=1.0):  # the run's stderr if it ended before serving
            assert driven.poll() is None, f"the run ended (exit {driven.returncode}): {driven.communicate()}"
            assert time.monotonic() < deadline, "the run's services did not appear within 120 s"
        features = _call(ex, first, first.srv_type.Request())
        f = set(features.features.features)
        assert {SimulatorFeatures.STEP_SIMULATION_SINGLE, SimulatorFeatures.STEP_SIMULATION_MULTIPLE,
                SimulatorFeatures.STEP_SIMULATION_ACTION, SimulatorFeatures.SIMULATION_RESET,
                SimulatorFeatures.SIMULATION_STATE_GETTING, SimulatorFeatures.SIMULATION_STATE_SETTING,
                SimulatorFeatures.SIMULATION_STATE_PAUSE} == f  # and nothing we do not do (spawning, worlds)
        get_state = client("get_simulation_state")
        deadline = time.monotonic() + 120
        while _call(ex, get_state, get_state.srv_type.Request()).state.state != SimulationState.STATE_PAUSED:
            assert time.monotonic() < deadline and driven.poll() is None, "the launcher never paused the run"
            time.sleep(0.1)
        flush = node.create_client(Trigger, resolve(service("recorder_flush").rel))

        def bag_counts():
            return json.loads(_call(ex, flush, Trigger.Request()).message)

        def settled_counts(n):
            """The counts once every per-tick topic has n messages (or after 20 s): a step's reply means the
            plant has its last coil/applied, and the recorder, another subscriber, may still be receiving it."""
            deadline = time.monotonic() + 20
            while True:
                counts = bag_counts()
                if all(counts[t.name] >= n for t in PER_TICK) or time.monotonic() > deadline:
                    return {t.name: counts[t.name] for t in PER_TICK}
                time.sleep(0.05)

        # nothing has run yet; a step while playing or past the end is refused
        assert all(bag_counts()[t.name] == 0 for t in PER_TICK)
        step = client("step_simulation")
        too_many = _call(ex, step, StepSimulation.Request(steps=N + 1))
        assert too_many.result.result == Result.RESULT_OPERATION_FAILED and "ticks left" in too_many.result.error_message
        # step 100 ticks: the bag holds exactly 100 ticks of every per-tick topic
        assert _call(ex, step, StepSimulation.Request(steps=100), idempotent=False).result.result == Result.RESULT_OK
        assert settled_counts(100) == {t.name: 100 for t in PER_TICK}
        # reset: back to t = 0, still paused, nothing more published
        reset = client("reset_simulation")
        assert _call(ex, reset, ResetSimulation.Request()).result.result == Result.RESULT_OK
        assert _call(ex, get_state, get_state.srv_type.Request()).state.state == SimulationState.STATE_PAUSED
        assert all(bag_counts()[t.name] == 100 for t in PER_TICK)
        # step in pieces: 37 by the service, 63 by the action (with feedback)
        assert _call(ex, step, StepSimulation.Request(steps=37), idempotent=False).result.result == Result.RESULT_OK
        spec = service("simulate_steps")
        action = ActionClient(node, import_type(spec.srvtype), resolve(spec.rel))
        assert action.wait_for_server(timeout_sec=60)
        # prime the action's goal and result services with a goal that is refused (0 steps) before the real one
        from vesselbot_ros.nodes.calls import Resend

        refused = Resend(lambda: action.send_goal_async(action._action_type.Goal(steps=0)))
        assert spin_until(ex, refused.done, 60) and refused.result().accepted
        aborted = Resend(refused.result().get_result_async)
        assert spin_until(ex, aborted.done, 60)
        assert aborted.result().result.result.result == Result.RESULT_OPERATION_FAILED
        feedback = []
        goal = action.send_goal_async(action._action_type.Goal(steps=63),
                                      feedback_callback=lambda m: feedback.append(
                                          (m.feedback.completed_steps, m.feedback.remaining_steps)))
        ex.spin_until_future_complete(goal, timeout_sec=60)
        assert goal.result().accepted
        res = goal.result().get_result_async()
        ex.spin_until_future_complete(res, timeout_sec=120)
        assert res.result().result.result.result == Result.RESULT_OK
        # feedback is a topic and the result a service reply: the last feedback (sent before the result) may
        # still be on its way when the result arrives, so it is waited for (bounded), not assumed in
        assert spin_until(ex, lambda: bool(feedback) and feedback[-1] == (63, 0), 30), feedback
        assert all(c + r == 63 for c, r in feedback) and [c for c, _ in feedback] == sorted(c for c, _ in feedback)
        assert settled_counts(200) == {t.name: 200 for t in PER_TICK}
        # play to the end
        play = client("set_simulation_state")
        req = SetSimulationState.Request()
        req.state.state = SimulationState.STATE_PAUSED  # first: the state it is in (harmless if sent twice)
        assert _call(ex, play, req).result.result in (SetSimulationState.Response.ALREADY_IN_TARGET_STATE,
                                                     Result.RESULT_OK)
        req.state.state = SimulationState.STATE_PLAYING
        assert _call(ex, play, req, idempotent=False).result.result == Result.RESULT_OK
        again = _call(ex, play, req, idempotent=False)
        assert again.result.result in (SetSimulationState.Response.ALREADY_IN_TARGET_STATE, Result.RESULT_INCORRECT_STATE)
        _out, err = driven.communicate(timeout=300)
        assert driven.returncode == 0, err[-3000:]
    finally:
        if driven.poll() is None:
            driven.kill()
            driven.communicate()
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        restore_process_env(saved)

    plain = subprocess.run(run_cmd(*common, "--record-dir", str(tmp_path / "plain")), cwd=tmp_path,
                           capture_output=True, text=True, timeout=300)
    assert plain.returncode == 0, plain.stderr[-3000:]
    a = _per_tick_messages(tmp_path / "driven")
    b = _per_tick_messages(tmp_path / "plain")
    for t in PER_TICK:
        assert len(b[t.name]) == N and len(a[t.name]) == 100 + N, (t.name, len(a[t.name]), len(b[t.name]))
        assert a[t.name][:100] == b[t.name][:100], t.name  # the steps before the reset
        assert a[t.name][100:] == b[t.name], t.name  # after the reset: stepped in pieces, then played
