"""The ``simulation_interfaces`` standard on the plant: play, pause, step, reset and query the run.

:class:`SimulationControl` is the plant process's second node
(:data:`~vesselbot_ros.graph_spec.SIMULATION_NODE`), spun by its own
executor on its own thread.  It serves the standard's services and the
``SimulateSteps`` action under their usual names, relative to the graph's
namespace (:data:`~vesselbot_ros.graph_spec.SIMULATION_SERVICES`), so a
client written for Gazebo, Isaac Sim or O3DE drives vesselbot unchanged.
A call that has to wait (StepSimulation returns when its ticks are done)
waits on this thread while the plant node goes on stepping on its own; the
two meet only in the plant's gate methods (:meth:`PlantNode.play`,
:meth:`~PlantNode.pause`, :meth:`~PlantNode.step`, ...), under the plant's
lock.

What it supports (``GetSimulatorFeatures`` reports exactly this):

* state getting and setting, including paused: *stopped* (not started, or
  stopped: at t = 0), *playing*, *paused*; ``STATE_QUITTING`` ends the run;
* lockstep only: ``StepSimulation`` (N >= 1 control ticks) and the
  ``SimulateSteps`` action (feedback: completed / remaining ticks, coalesced
  when several ticks complete between two wake-ups; cancelable), and
  ``ResetSimulation`` (time and state together: the loop is deterministic,
  so the same seed gives the same messages again).  Nothing is ever spawned,
  so ``SCOPE_SPAWNED`` has nothing to do.
"""

from __future__ import annotations

import threading
from typing import Any

import rclpy
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import Result, SimulationState, SimulatorFeatures
from simulation_interfaces.srv import ResetSimulation, SetSimulationState
from std_srvs.srv import Trigger

from vesselbot_ros.graph_spec import ROLES, SIMULATION_NODE, import_type, loop_roles, reset_service_key, service
from vesselbot_ros.nodes.calls import Resend
from vesselbot_ros.sim.kinds import delivers_frames

__all__ = ["SimulationControl", "features", "STOPPED", "PLAYING", "PAUSED", "ALREADY"]

#: Simulation states (simulation_interfaces' SimulationState, by name).
STOPPED, PLAYING, PAUSED = "stopped", "playing", "paused"
#: What :meth:`PlantNode.play` / :meth:`PlantNode.pause` return when nothing changes.
ALREADY = "already in the target state"

#: How long a reset waits for the tick in flight and for each node's reset (wall s).
RESET_TIMEOUT_S = 30.0


def features(lockstep: bool) -> list[int]:
    """The SimulatorFeatures this simulator supports (stepping and reset need a lockstep run)."""
    F = SimulatorFeatures
    out = [F.SIMULATION_STATE_GETTING, F.SIMULATION_STATE_SETTING, F.SIMULATION_STATE_PAUSE]
    if lockstep:
        out += [F.SIMULATION_RESET, F.STEP_SIMULATION_SINGLE, F.STEP_SIMULATION_MULTIPLE, F.STEP_SIMULATION_ACTION]
    return out


class SimulationControl:
    """The simulation_interfaces server of a :class:`~vesselbot_ros.nodes.plant_node.PlantNode` (see module doc)."""

    def __init__(self, plant: Any) -> None:
        self.plant = plant
        self.node = rclpy.create_node(SIMULATION_NODE, namespace=plant.get_namespace(), context=plant.context)
        group = ReentrantCallbackGroup()
        handlers = {"get_simulator_features": self._features, "get_simulation_state": self._get_state,
                    "set_simulation_state": self._set_state, "step_simulation": self._step,
                    "reset_simulation": self._reset}
        self._services = [self.node.create_service(import_type(service(k).srvtype), service(k).rel, fn,
                                                   callback_group=group) for k, fn in handlers.items()]
        spec = service("simulate_steps")
        self._action = ActionServer(self.node, import_type(spec.srvtype), spec.rel, execute_callback=self._simulate,
                                    cancel_callback=lambda _goal: CancelResponse.ACCEPT, callback_group=group)
        self._reset_clients = {r.name: self.node.create_client(import_type(service(reset_service_key(r.name)).srvtype),
                                                               service(reset_service_key(r.name)).rel,
                                                               callback_group=group)
                               for r in ROLES if reset_service_key(r.name) in r.services
                               and r.name in loop_roles(delivers_frames(plant.scenario))}
        self._executor = MultiThreadedExecutor(num_threads=4, context=plant.context)
        self._executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="simulation_interfaces", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and rclpy.ok(context=self.plant.context):
            try:
                self._executor.spin_once(timeout_sec=0.1)
            except Exception:  # shutting down: the context went away under the executor (else re-raised)
                if self._stop.is_set() or not rclpy.ok(context=self.plant.context):
                    return
                raise

    def close(self) -> None:
        """Stop the thread and destroy the node (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._executor.shutdown(timeout_sec=1.0)
        self._action.destroy()
        self.node.destroy_node()

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _result(resp: Any, code: int, message: str = "") -> Any:
        resp.result.result = code
        resp.result.error_message = message
        return resp

    def _state_msg(self) -> Any:
        p = self.plant
        if p.finished:
            return SimulationState(state=SimulationState.STATE_STOPPED)
        code = {PLAYING: SimulationState.STATE_PLAYING, PAUSED: SimulationState.STATE_PAUSED}.get(
            p.sim_state, SimulationState.STATE_STOPPED)
        return SimulationState(state=code)

    def _wait_ticks(self, target: int, on_progress: Any = None, cancelled: Any = None) -> bool:
        """Wait until the plant reached tick ``target`` (True), or the run ended / the goal was cancelled (False)."""
        p = self.plant
        while rclpy.ok(context=p.context) and not self._stop.is_set():
            reached = p.wait_for_tick(target, 0.1)
            if on_progress is not None:
                on_progress(min(p.k, target))
            if reached:
                return p.k >= target
            if cancelled is not None and cancelled():
                return False
        return False

    # ------------------------------------------------------------------ services
    def _features(self, request: Any, response: Any) -> Any:
        response.features.features = features(self.plant.lockstep)
        response.features.custom_info = (
            f"vesselbot_ros: one step = one control tick (dt = {self.plant.dt:g} s); "
            + ("lockstep run: stepping and reset supported" if self.plant.lockstep
               else "real-time run: play / pause only"))
        return response

    def _get_state(self, request: Any, response: Any) -> Any:
        response.state = self._state_msg()
        return self._result(response, Result.RESULT_OK)

    def _set_state(self, request: Any, response: Any) -> Any:
        target = request.state.state
        p = self.plant
        if target == SimulationState.STATE_QUITTING:
            p.quit()
            return self._result(response, Result.RESULT_OK)
        if p.finished:
            return self._result(response, Result.RESULT_INCORRECT_STATE, "the run has finished")
        if target == SimulationState.STATE_PLAYING:
            why = p.play()
        elif target == SimulationState.STATE_PAUSED:
            why = p.pause()
        elif target == SimulationState.STATE_STOPPED:
            if p.sim_state == STOPPED:
                why = ALREADY
            elif not p.lockstep:
                return self._result(response, Result.RESULT_FEATURE_UNSUPPORTED,
                                    "stopping (pause and reset) needs a lockstep run")
            else:
                why = self._reset_all(STOPPED)
                if why:
                    return self._result(response, SetSimulationState.Response.STATE_TRANSITION_ERROR, why)
        else:
            return self._result(response, SetSimulationState.Response.INCORRECT_TRANSITION,
                                f"state {target} cannot be set (no worlds are loaded or unloaded here)")
        if why == ALREADY:
            return self._result(response, SetSimulationState.Response.ALREADY_IN_TARGET_STATE, why)
        if why:
            return self._result(response, SetSimulationState.Response.STATE_TRANSITION_ERROR, why)
        return self._result(response, Result.RESULT_OK)

    def _step(self, request: Any, response: Any) -> Any:
        why, target = self.plant.step(int(request.steps))
        if why:
            return self._result(response, Result.RESULT_OPERATION_FAILED, why)
        if not self._wait_ticks(target):
            return self._result(response, Result.RESULT_OPERATION_FAILED,
                                f"the run ended at tick {self.plant.k} before tick {target}")
        return self._result(response, Result.RESULT_OK)

    def _reset(self, request: Any, response: Any) -> Any:
        scope = int(request.scope)
        R = ResetSimulation
        both = R.Request.SCOPE_TIME | R.Request.SCOPE_STATE
        if scope != R.Request.SCOPE_DEFAULT and scope & both != both:
            return self._result(response, Result.RESULT_FEATURE_UNSUPPORTED,
                                "time and state reset together only (SCOPE_DEFAULT, SCOPE_ALL or TIME|STATE): "
                                "the lockstep loop is one deterministic state")
        if not self.plant.lockstep:
            return self._result(response, Result.RESULT_FEATURE_UNSUPPORTED, "reset needs a lockstep run")
        if self.plant.finished:
            return self._result(response, Result.RESULT_INCORRECT_STATE, "the run has finished")
        prior = self.plant.hold()
        why = self._reset_all(prior, held=True)
        if why:
            return self._result(response, Result.RESULT_OPERATION_FAILED, why)
        return self._result(response, Result.RESULT_OK)

    def _reset_all(self, then: str, held: bool = False) -> str:
        """Hold the gate, wait for the tick in flight, reset every loop node, restart the plant in ``then``."""
        p = self.plant
        if not held:
            p.hold()
        if not p.wait_idle(RESET_TIMEOUT_S):
            return f"the tick in flight did not complete within {RESET_TIMEOUT_S:g} s"
        for name, client in self._reset_clients.items():
            if not client.wait_for_service(timeout_sec=2.0):
                return f"node {name} does not serve {client.srv_name} (a node of your own in its slot?)"
            call = Resend.service(client, Trigger.Request())  # a second reset of a held node changes nothing
            answered = call.wait(RESET_TIMEOUT_S)  # this executor's other threads spin the answer in
            if not answered or call.result() is None or not call.result().success:
                msg = call.result().message if answered and call.result() is not None else "no answer"
                return f"node {name} did not reset: {msg}"
        p.restart(then)
        return ""

    # ------------------------------------------------------------------ action
    def _simulate(self, goal: Any) -> Any:
        result = SimulateSteps.Result()
        n = int(goal.request.steps)
        why, target = self.plant.step(n)
        if why:
            goal.abort()
            result.result.result = Result.RESULT_OPERATION_FAILED
            result.result.error_message = why
            return result
        start = target - n
        last = [-1]

        def progress(k: int) -> None:
            if k != last[0]:
                last[0] = k
                goal.publish_feedback(SimulateSteps.Feedback(completed_steps=k - start, remaining_steps=target - k))

        done = self._wait_ticks(target, on_progress=progress, cancelled=lambda: goal.is_cancel_requested)
        if goal.is_cancel_requested and not done:
            self.plant.cancel_steps()  # no further tick goes through; the one in flight completes
            goal.canceled()
            result.result.result = Result.RESULT_OK
            result.result.error_message = f"cancelled after {self.plant.k - start} of {n} steps"
            return result
        if not done:
            goal.abort()
            result.result.result = Result.RESULT_OPERATION_FAILED
            result.result.error_message = f"the run ended at tick {self.plant.k} before tick {target}"
            return result
        goal.succeed()
        result.result.result = Result.RESULT_OK
        return result
