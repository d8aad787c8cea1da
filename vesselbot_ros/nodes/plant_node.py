"""Plant simulator node: the robot's true dynamics, ground truth, and the ``/clock``.

Thin adapter over :class:`vesselbot_ros.sim.plant.PlantSimulator` (built by
:func:`vesselbot_ros.sim.closed_loop.build_stage`, like the pure runner).

Ports (frame ``vessel``; k = tick, t_k = k * dt, dt = 1 / sim.control_rate_Hz):

==========================  ===================================  ==============  =========================
port                        type                                 rate            units
==========================  ===================================  ==============  =========================
out ``/clock``              rosgraph_msgs/Clock                  per tick        s (t_k)
out ``/vesselbot/truth``    vesselbot_msgs/PlantState            per tick        m, m/s, N, T/m
out ``vessel_markers``      visualization_msgs/MarkerArray       once, latched   m (see below)
out ``coil/stall``          std_msgs/Header                      a late tick     s (t_k)
in  ``coil/applied``        geometry_msgs/Vector3Stamped         per tick        T/m
srv ``run_control``         vesselbot_msgs/RunControl            on demand       -
srv/action simulation_interfaces (see below)                     on demand       -
out ``/diagnostics``        diagnostic_msgs/DiagnosticArray      1 Hz wall       tick, sim_time_s, finished
==========================  ===================================  ==============  =========================

Lockstep (``graph.mode: lockstep``): on START, publish truth 0 and ``/clock``
t_0 (truth first: it starts the tick's critical path, imager -> observer ->
controller -> coil driver -> plant, while ``/clock`` only feeds the reference
and users' nodes); each ``coil/applied`` stamped t_k integrates
[t_k, t_k+1] under it and publishes tick k+1.  After tick n-1 (n = ``sim.n_ticks``) the run is finished:
final diagnostics (``finished: true``), RunControl STATUS reports it.

Pausing and stepping (lockstep): the plant holds a gate in front of each
tick.  Playing, it publishes tick k+1 as soon as ``coil/applied`` k has been
integrated; paused, it integrates [t_k, t_k+1] but holds tick k+1 until a
step allows it, so ``StepSimulation(N)`` from a paused plant at tick k
publishes ticks k..k+N-1 and returns once ``coil/applied`` k+N-1 has been
integrated: the bag then holds exactly those N more ticks, and a run stepped
in pieces publishes what an unpaused run publishes, message for message (the
nodes only ever see ticks, never wall time).  The gate is the only thing
added to the hot path (a lock and a state test per tick).

The standard's services and action (``simulation_interfaces``, declared in
the graph spec, :data:`~vesselbot_ros.graph_spec.SIMULATION_SERVICES`) are
served by :class:`~vesselbot_ros.nodes.simulation_control.SimulationControl`,
a second node of this process on its own thread, so a call that waits for
its ticks never blocks this node's stepping.  States: *stopped* (before the
run starts, or after a stop: at t = 0, nothing published), *playing*,
*paused*.  ResetSimulation (lockstep) pauses at the end of the tick in
flight, calls every loop node's ``reset`` service, rebuilds the plant from
the scenario and returns to the state it had (playing goes on from t = 0).

Lockstep watchdog: when ``coil/applied`` of the tick in flight has not come
within ``graph.stall_timeout_s`` of wall time since the tick was published
(the controller died or hangs), the plant publishes ``coil/stall`` stamped
t_k (latched) and the coil driver answers the tick itself (holding, then
ramping its output to zero).  Until an answer comes for a tick it did not
have to ask for, commands count as lost and the plant asks after
``min(graph.stall_timeout_s, LOST_GRACE_S)`` instead, so the ramp runs at
graph speed (the driver defers a request while a live but late controller
still sends commands, see the coil driver node).  A tick held at the gate
(paused, stepping) is never asked for.

Real-time (``graph.mode: realtime``): on START a wall-clock timer advances the
plant by as many ticks as ``graph.real_time_factor`` asks, applying the latest
``coil/applied`` (zero-order hold), and publishes ``/clock`` and truth per tick.

The vessel markers (latched, published once at start-up, for viewers): the straight vessel's two
walls at the nominal diameter; a planar network's meshed wall (a LINE_LIST: the wall whose distance
the plant computes) and centrelines; a 3-D tree's (a network whose branches give ``y_m``,
:attr:`~vesselbot_ros.vessels.network.VesselNetworkParams.is_3d`) lumen wall as a translucent
TRIANGLE_LIST and its 3-D centrelines (:func:`network_scene_markers`).

Input checks (see :meth:`VesselbotNode.check`): ``coil/applied`` with a wrong
frame_id, a non-finite value or (planar scenarios) non-zero y, or (lockstep) a tick other than
the current one is rejected (WARN diagnostics); the plant then keeps waiting
(lockstep) or keeps the previous gradient (real-time).  It warns every
``graph.plant_wait_warn_s`` of wall time while waiting.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from rclpy.timer import Timer
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Header
from vesselbot_msgs.msg import PlantState
from vesselbot_msgs.srv import RunControl
from visualization_msgs.msg import MarkerArray

from vesselbot_ros.graph_spec import role
from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.base import VesselbotNode
from vesselbot_ros.nodes.process import run_node
from vesselbot_ros.nodes.simulation_control import ALREADY, PAUSED, PLAYING, STOPPED, SimulationControl
from vesselbot_ros.physics.blood_flow import Vessel
from vesselbot_ros.physics.kernel import fluid_velocity_x, network_geometry
from vesselbot_ros.physics.tree_vessel import tree_geometry
from vesselbot_ros.scanner.hardware import effective_coil_limits
from vesselbot_ros.sim.closed_loop import build_stage
from vesselbot_ros.vessels import tree_field
from vesselbot_ros.vessels.cfd import network_wall
from vesselbot_ros.vessels.network import VesselNetworkParams, load_network
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

__all__ = ["PlantNode", "main", "PLANT_STAT_NAMES", "STOPPED", "PLAYING", "PAUSED", "ALREADY", "LOST_GRACE_S",
           "network_scene_markers"]

#: Names of ``PlantSimulator.stats`` entries, as the pure runner reports them.
PLANT_STAT_NAMES = role("plant").counters
#: Lockstep: wall time (s) a tick waits for its coil/applied once commands are lost (see the module docstring).
LOST_GRACE_S = 0.02
#: Lockstep: period (s, wall) of the check for a late coil/applied while commands are lost; while ticks
#: are answered in time the check runs every tenth of ``graph.stall_timeout_s``, at most every 50 ms
#: (a timer that wakes the plant 200 times a second costs the loop CPU on every tick).
STALL_POLL_S = 0.005
def network_scene_markers(net: VesselNetworkParams, blood: Any, robot_radius_m: float) -> MarkerArray:
    """The vessel markers of a network: a 3-D tree's wall mesh and 3-D centrelines, else the planar meshed wall.

    A 3-D tree's wall is the one its plant computes with (:func:`vesselbot_ros.vessels.tree_field.wall_mesh`:
    shipped, cached or solved with the tree's flow; 9 912 triangles for the carotid, 22 958 for
    synthetic_tree_3d: 1.7 MB of markers).
    """
    if net.is_3d:  # the vessel kind's edge: a tree's surface mesh, or the planar network's wall segments
        vertices, triangles = tree_field.wall_mesh(net, blood)
        return cv.network_markers_3d(NetworkGeometry(net, dims=3), vertices, triangles, robot_radius_m)
    return cv.network_markers(NetworkGeometry(net), network_wall(net, blood).segments, robot_radius_m)


class PlantNode(VesselbotNode):
    """The plant simulator (see module docstring for ports and modes)."""

    ROLE = "plant"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.ROLE, **kwargs)
        self.dt = self.scenario.sim.dt_control_s
        self._vessel = Vessel(self.scenario.physics)
        # the gate's lock: taken by this node's callbacks and by the simulation_interfaces thread
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._wake_tick: int | None = None  # the lowest tick a thread waits for (wait_for_tick)
        self._idle_waiters = 0  # threads waiting for the loop to be idle (wait_idle)
        self.sim_state = STOPPED
        self.running = False
        self.paused = False
        self.reset_state()
        self._wait_since = time.monotonic()
        self._wall_start = 0.0
        self._first_emit_wall: float | None = None
        self._first_emit_tick = 0
        self._last_emit_wall = 0.0
        #: real time: wall time spent paused between published ticks (s), and when the current pause began
        self._paused_wall_s = 0.0
        self._pause_began: float | None = None
        self.add_publisher("clock", Clock)
        self.add_publisher("truth", PlantState)
        self.add_publisher("vessel_markers", MarkerArray)
        self.add_publisher("coil_stall", Header)
        self.add_subscription("coil_applied", Vector3Stamped, self._on_applied)
        self.add_service("run_control", RunControl, self._on_run_control)
        ref = self.scenario.reference
        self._network = bool(self.scenario.physics.vessel.network)
        if self._network:
            markers = network_scene_markers(load_network(self.scenario.physics.vessel.network),
                                            self.scenario.physics.blood, self.scenario.physics.robot.radius_m)
        else:
            markers = cv.vessel_markers(min(ref.anchors_x_m) - 1e-3, max(ref.anchors_x_m) + 1e-3,
                                        self.scenario.physics.vessel.diameter_m, self.scenario.physics.robot.radius_m)
        self.publish("vessel_markers", markers)
        self._rt_timer: Timer | None = None
        self._poll = self.create_timer(0.05, self._housekeeping, clock=self._wall)
        if self.lockstep:
            slow = min(0.05, max(STALL_POLL_S, self.graph.stall_timeout_s / 10))
            self._stall_timer = self.create_timer(slow, self._stall_check, clock=self._wall)
            self._stall_fast = self.create_timer(STALL_POLL_S, self._stall_check, clock=self._wall)
            self._stall_fast.cancel()  # runs while commands are lost
        # the truth message's own compiled calls (flow, diameter, the network's geometry) before tick 0: a
        # throwaway message, nothing published and no state touched
        self._truth(self.plant.output(with_forces=True))
        self.simulation = SimulationControl(self)

    def reset_state(self) -> None:
        """The plant as built from the scenario, at tick 0, nothing published for it yet."""
        self.plant = build_stage(self.scenario, self.stage)
        self.k = 0
        self._g = np.zeros(self.dims)
        self._budget = 0  # ticks a paused plant may still publish (steps asked for)
        self._held = True  # tick k is computed but not published
        self._stall_sent = -1  # lockstep: the last tick the coil driver was asked to answer itself
        self._commands_lost = False  # lockstep: the last tick asked for has not been followed by a tick answered in time

    def destroy_node(self) -> None:
        self.simulation.close()
        super().destroy_node()

    # ------------------------------------------------------------------ run control
    def _start(self, paused: bool = False) -> None:
        self.running = True
        self.sim_state = PAUSED if paused else PLAYING
        self._wait_since = time.monotonic()
        if self.lockstep:
            self._release()
            return
        self.paused = paused
        self._pause_began = time.monotonic() if paused else None
        self._held = False
        # tick 0 is due now, and every later tick on the same schedule: the nodes anchor their periods on
        # tick 0's arrival, so a schedule started after tick 0 went out (its first emit takes a while)
        # made every later tick look one period late
        self._wall_start = time.monotonic()
        self._anchor = self._wall_start
        self._rt_timer = self.create_timer(
            min(self.dt / self.graph.real_time_factor, 0.01), self._realtime_tick, clock=self._wall
        )
        self._emit()

    def _on_run_control(self, req: Any, resp: Any) -> Any:
        with self._lock:
            return self._run_control(req, resp)

    def _run_control(self, req: Any, resp: Any) -> Any:
        c = req.command
        resp.success = True
        if c == RunControl.Request.START:
            if self.running or self.finished:
                resp.success = False
                resp.message = "already started"
            else:
                self._start()
                resp.message = "started"
        elif c == RunControl.Request.PAUSE:
            why = self.pause() if self.running else "pause applies to a running run only"
            resp.success = not why
            resp.message = why or "paused"
        elif c == RunControl.Request.RESUME:
            why = self.play() if self.sim_state == PAUSED else "not paused"
            resp.success = not why
            resp.message = why or "resumed"
        elif c == RunControl.Request.STOP:
            self._finish()
            resp.message = "stopped"
        else:
            resp.message = "finished" if self.finished else ("running" if self.running else "waiting for START")
        resp.sim_time = self.k * self.dt
        resp.tick = self.k
        resp.finished = self.finished
        return resp

    # ------------------------------------------------------------------ simulation states (any thread)
    def play(self) -> str:
        """Stopped or paused -> playing; returns '' or why not."""
        return self._enter(PLAYING)

    def pause(self) -> str:
        """Stopped or playing -> paused (a stopped run starts paused, at t = 0); returns '' or why not.

        Lockstep: the tick in flight completes; the next one is held at the gate.
        """
        return self._enter(PAUSED)

    def _enter(self, state: str) -> str:
        with self._lock:
            if self.finished:
                return "the run has finished"
            if self.sim_state == state:
                return ALREADY
            if not self.running:
                self._start(paused=state == PAUSED)
                return ""
            self.sim_state = state
            self._budget = 0
            if state == PAUSED:
                self.paused = not self.lockstep
                self._pause_began = None if self.lockstep else time.monotonic()
            elif self.lockstep:
                self._release()
            else:
                self.paused = False
                if self._pause_began is not None:  # a pause is no wall time of the run's (its average factor)
                    self._paused_wall_s += time.monotonic() - self._pause_began
                    self._pause_began = None
                self._wall_start = time.monotonic() - self.k * self.dt / self.graph.real_time_factor
                self._anchor = self._wall_start
            return ""

    def step(self, n: int) -> tuple[str, int]:
        """Paused, lockstep: let ``n`` more ticks through; returns ('' or why not, the tick reached when done)."""
        with self._lock:
            if not self.lockstep:
                return "stepping needs a lockstep run (graph.mode: lockstep)", self.k
            if self.finished:
                return "the run has finished", self.k
            if self.sim_state != PAUSED:
                return f"the simulation is {self.sim_state}, not paused", self.k
            left = self.n_ticks - self.k - self._budget
            if n < 1 or n > left:
                return f"steps must be in [1, {left}] (ticks left in the run), got {n}", self.k
            self._budget += n
            target = self.k + self._budget
            self._release()
            return "", target

    def cancel_steps(self) -> None:
        """Drop the steps still owed (a cancelled SimulateSteps goal)."""
        with self._lock:
            self._budget = 0

    def wait_for_tick(self, target: int, timeout_s: float) -> bool:
        """Block (another thread) until tick ``target`` is reached or the run finished; False on timeout.

        A tick wakes a waiter only when it reaches the lowest tick waited for, not on every tick: a
        stepping client's thread would otherwise take the GIL from the loop once per tick.
        """
        end = time.monotonic() + timeout_s
        with self._cond:
            while not (self.k >= target or self.finished):
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._wake_tick = target if self._wake_tick is None else min(self._wake_tick, target)
                self._cond.wait(left)
            return True

    def wait_idle(self, timeout_s: float) -> bool:
        """Block (another thread) until no tick is in flight; False on timeout."""
        with self._cond:
            self._idle_waiters += 1
            try:
                return self._cond.wait_for(lambda: self.idle, timeout_s)
            finally:
                self._idle_waiters -= 1

    def hold(self) -> str:
        """Close the gate for a reset; returns the state to go back to."""
        with self._lock:
            prior = self.sim_state
            if self.running:
                self.sim_state = PAUSED
                self._budget = 0
            return prior

    def restart(self, state: str) -> None:
        """After every node reset: rebuild the plant at t = 0 and go on in ``state`` (stopped: not started)."""
        with self._lock:
            self.reset_state()
            self.tick_now = -1
            self.period_tick = -1
            if state == STOPPED:
                self.running = False
                self.sim_state = STOPPED
            else:
                self.running = True
                self.sim_state = state
                self._release()
            self._cond.notify_all()

    def quit(self) -> None:
        """End the run now (the launcher then stops every node and finalises the bag)."""
        with self._lock:
            if not self.finished:
                self._finish()

    def _housekeeping(self) -> None:
        with self._lock:
            if self.graph.autostart and not self.running and not self.finished and self.wired():
                self._start()
            waiting = self.lockstep and not self.idle
        if waiting:
            waited = time.monotonic() - self._wait_since
            if waited > self.graph.plant_wait_warn_s:
                self._wait_since = time.monotonic()
                self.get_logger().warning(f"lockstep: still waiting for coil/applied of tick {self.k} ({waited:.1f} s)")

    def _stall_check(self) -> None:
        """Lockstep: ask the coil driver to answer the tick in flight itself when its coil/applied is late."""
        with self._lock:
            if not self._commands_lost and not self._stall_fast.is_canceled():
                self._stall_fast.cancel()  # commands came again (or a reset): back to the slow check
            if self.idle or self._stall_sent == self.k:  # no tick in flight, or this one asked for already
                return
            wait = self.graph.stall_timeout_s
            if self._commands_lost:
                wait = min(wait, LOST_GRACE_S)
            if time.monotonic() - self._last_emit_wall < wait:
                return
            self._stall_sent, self._commands_lost = self.k, True
            if self._stall_fast.is_canceled():
                self._stall_fast.reset()
            self.publish("coil_stall", cv.header(cv.tick_time(self.k, self.dt)))

    # ------------------------------------------------------------------ ticks
    def _emit(self) -> None:
        """Publish /clock and truth for the current tick k."""
        self.tick_now = self.k
        now = time.monotonic()
        if self._first_emit_wall is None:
            self._first_emit_wall = now
            self._first_emit_tick = self.k
        self._last_emit_wall = now
        out = self.plant.output(with_forces=True)
        if self.lockstep:  # truth first: it starts the tick's critical path (imager -> ... -> plant)
            self.publish("truth", self._truth(out))
            self.publish("clock", cv.clock_flat(out.t_s))
        else:  # real time: a node takes the tick from /clock, then its inputs of that tick
            self.publish("clock", cv.clock_flat(out.t_s))
            self.publish("truth", self._truth(out))
        self.period_done(self.k)  # real time: tick k is due at wall start + k * dt / real_time_factor

    def _truth(self, out: Any) -> Any:
        """The truth of the current tick, in its flat form (``PlantState``).

        In a network (and a 3-D tree) the gaps are to the nearest wall and the one across the local diameter,
        ``wall_gap_upper`` the one whose inward normal points down (``PlantOutput.wall``).
        """
        t = out.t_s
        r = self.scenario.physics.robot.radius_m
        blood: tuple[float, ...]
        # the vessel's edge, as the plant's own (physics.integrator): a tree's sampled field, the planar network's
        # grid, or the straight vessel's two walls
        if self.dims == 3:
            k = self.plant.packed
            s_t, *_n, d, _eta, vfx, vfy, vfz = tree_geometry(t, *out.p.tolist(), self.plant.p, k.W, k.F, k.fh)
            blood = (float(vfx), float(vfy), float(vfz))
        elif self._network:
            s_t, _nx, _nz, d, _eta, vfx, vfz = network_geometry(t, float(out.p[0]), float(out.p[1]), self.plant.p)
            blood = (float(vfx), float(vfz))
        else:
            x, z = float(out.p[0]), float(out.p[1])
            d = self._vessel.diameter(t)
            blood = (float(fluid_velocity_x(t, x, z, self.plant.p)), 0.0)
            gap_up, gap_lo = 0.5 * d - z - r, z + 0.5 * d - r
        if self._network:
            near, far = s_t - r, d - s_t - r  # gaps to the nearest wall and the opposite one
            gap_up, gap_lo = (near, far) if out.wall > 0 else (far, near)
        return cv.plant_state_flat(self.k, t, out.p, out.v, blood, d, gap_up, gap_lo, out.delta_m, out.in_contact,
                                   out.contact_phase, self._g, out.forces, self.dims)

    def _advance(self, g: np.ndarray) -> None:
        self.plant.step(g)
        self._g = g
        self.k += 1
        self._wait_since = time.monotonic()
        if self.k >= self.n_ticks:
            self._finish()
        elif self.lockstep:
            self._held = True
            self._release()
        else:
            self._emit()
        if (self._wake_tick is not None and self.k >= self._wake_tick) or (self._idle_waiters and self.idle):
            self._wake_tick = None  # waiters still short of their tick set it again
            self._cond.notify_all()

    # ------------------------------------------------------------------ the gate (lockstep), under self._lock
    def _release(self) -> None:
        """Publish the held tick if the state lets it through (playing, or a step still owed)."""
        if not self._held or self.finished or not self.running:
            return
        if self.sim_state == PAUSED:
            if self._budget <= 0:
                return
            self._budget -= 1
        elif self.sim_state != PLAYING:
            return
        self._held = False
        self._emit()

    @property
    def idle(self) -> bool:
        """True when no tick is in flight (the loop waits at the gate, or the run has not started or is over)."""
        return self._held or self.finished or not self.running

    def _finish(self) -> None:
        self.running = False
        if self._rt_timer is not None:
            self._rt_timer.cancel()
        self.mark_finished()
        self._cond.notify_all()

    def _on_applied(self, msg: Any) -> None:
        """The applied gradient, in its flat form (``Vector3Stamped``: ``header_stamp_sec``, ``vector_x`` ...)."""
        with self._lock:
            self._applied(msg)

    def _applied(self, msg: Any) -> None:
        x, y, z = msg.vector_x, msg.vector_y, msg.vector_z
        stamp = cv.stamp_ns(msg)
        if not self.check("coil_applied", frame_id=msg.header_frame_id_cdr, values=(x, y, z), y_values=(y,),
                          stamp_ns=None if self.lockstep else stamp):
            return
        g = cv.vector_array(x, y, z, self.dims)
        if not self.lockstep:
            self.count_received("coil_applied")
            self._g_latest = g
            return
        k, on_grid = cv.tick_of_ns(stamp, self.dt)
        if not on_grid:
            self.reject("coil_applied", "off_tick_stamp", f"stamp {stamp} ns")
            return
        if not self.running or k != self.k or self._held:
            self.reject("coil_applied", "stale_tick" if k < self.k or not self.running else "future_tick",
                        f"tick {k}, plant at tick {self.k}")
            return
        self.count_received("coil_applied")
        if self._stall_sent != k:  # answered without being asked: the commands come again
            self._commands_lost = False
        self._advance(g)

    def _realtime_tick(self) -> None:
        with self._lock:
            self._realtime_ticks()

    def _realtime_ticks(self) -> None:
        if not self.running or self.paused or self.finished:
            return
        target = int((time.monotonic() - self._wall_start) * self.graph.real_time_factor / self.dt)
        # never more than 50 ticks per call: a stalled machine catches up gradually
        for _ in range(min(target - self.k, 50)):
            self._advance(self._slewed(getattr(self, "_g_latest", self._g)))
            if self.finished:
                break

    def _slewed(self, g: np.ndarray) -> np.ndarray:
        """Real time: the gradient the coils can reach in one tick from the last applied (per-axis slew limit).

        The driver limits slew between its own outputs; under load its outputs
        skip ticks, so the plant's input is limited again here, tick by tick.
        """
        step = effective_coil_limits(self.scenario.coil, self.scenario.dbdt).slew_rate_T_per_m_per_s * self.dt
        return self._g + np.clip(g - self._g, -step, step)

    def started(self) -> bool:
        return self.running

    @property
    def _run_wall_s(self) -> float:
        """Wall time from the first to the last tick published, the run's pauses (real time) left out."""
        if self._first_emit_wall is None:
            return 0.0
        return self._last_emit_wall - self._first_emit_wall - self._paused_wall_s

    @property
    def _run_sim_s(self) -> float:
        return 0.0 if self._first_emit_wall is None else (self.tick_now - self._first_emit_tick) * self.dt

    def diagnostic_values(self) -> dict[str, str]:
        return {
            "tick": str(self.k),
            "simulation_state": self.sim_state,
            "sim_time_s": repr(self.k * self.dt),
            "n_ticks": str(self.n_ticks),
            # wall time from tick 0 to the last tick published (s): what the launcher reports the run took
            "run_wall_s": repr(self._run_wall_s),
            # the sim time that advanced over it (first to last tick published) and their ratio, the average
            # real-time factor held (real time: the run fails if it falls more than 1 % below the asked factor)
            "run_sim_s": repr(self._run_sim_s),
            "real_time_factor_held": repr(self._run_sim_s / self._run_wall_s if self._run_wall_s > 0 else 0.0),
        } | {name: str(int(v)) for name, v in zip(PLANT_STAT_NAMES, self.plant.stats)}


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_plant``."""
    return run_node(PlantNode, argv, exit_process=True)


if __name__ == "__main__":
    sys.exit(main())
