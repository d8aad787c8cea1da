"""Plant simulator node: the robot's true dynamics, ground truth, and the ``/clock``.

Thin adapter over :class:`vesselbot_ros.sim.plant.PlantSimulator` (built by
:func:`vesselbot_ros.sim.closed_loop.build_stages`, like the pure runner).

Ports (frame ``vessel``; k = tick, t_k = k * dt, dt = 1 / sim.control_rate_Hz):

==========================  ===================================  ==============  =========================
port                        type                                 rate            units
==========================  ===================================  ==============  =========================
out ``/clock``              rosgraph_msgs/Clock                  per tick        s (t_k)
out ``/vesselbot/truth``    vesselbot_msgs/PlantState            per tick        m, m/s, N, T/m
out ``vessel_markers``      visualization_msgs/MarkerArray       once, latched   m
in  ``coil/applied``        geometry_msgs/Vector3Stamped         per tick        T/m
srv ``run_control``         vesselbot_msgs/RunControl            on demand       -
out ``/diagnostics``        diagnostic_msgs/DiagnosticArray      1 Hz wall       tick, sim_time_s, finished
==========================  ===================================  ==============  =========================

Lockstep (``graph.mode: lockstep``): on START, publish ``/clock`` t_0 and truth
0; each ``coil/applied`` stamped t_k integrates [t_k, t_k+1] under it and
publishes tick k+1.  After tick n-1 (n = ``sim.n_ticks``) the run is finished:
final diagnostics (``finished: true``), RunControl STATUS reports it.

Real-time (``graph.mode: realtime``): on START a wall-clock timer advances the
plant by as many ticks as ``graph.real_time_factor`` asks, applying the latest
``coil/applied`` (zero-order hold), and publishes ``/clock`` and truth per tick.

Input checks (see :meth:`VesselbotNode.check`): ``coil/applied`` with a wrong
frame_id, a non-finite value or non-zero y, or (lockstep) a tick other than
the current one is rejected (WARN diagnostics); the plant then keeps waiting
(lockstep) or keeps the previous gradient (real-time).  It warns every
``graph.plant_wait_warn_s`` of wall time while waiting.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from rosgraph_msgs.msg import Clock
from visualization_msgs.msg import MarkerArray

from vesselbot_msgs.msg import ForceBreakdown, PlantState
from vesselbot_msgs.srv import RunControl
from vesselbot_ros.graph_spec import role
from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.base import VesselbotNode, run_node, stamp_ns_of
from vesselbot_ros.physics.blood_flow import Vessel
from vesselbot_ros.physics.kernel import fluid_velocity_x, network_geometry
from vesselbot_ros.scanner.hardware import effective_coil_limits
from vesselbot_ros.sim.closed_loop import build_stages

__all__ = ["PlantNode", "main", "PLANT_STAT_NAMES"]

#: Names of ``PlantSimulator.stats`` entries, as the pure runner reports them.
PLANT_STAT_NAMES = role("plant").counters


class PlantNode(VesselbotNode):
    """The plant simulator (see module docstring for ports and modes)."""

    ROLE = "plant"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.ROLE, **kwargs)
        st = build_stages(self.scenario)
        self.plant = st.plant
        self.dt = self.scenario.sim.dt_control_s
        self._vessel = Vessel(self.scenario.physics)
        self.k = 0
        self.running = False
        self.paused = False
        self._g = np.zeros(2)
        self._wait_since = time.monotonic()
        self._wall_start = 0.0
        self.add_publisher("clock", Clock)
        self.add_publisher("truth", PlantState)
        self.add_publisher("vessel_markers", MarkerArray)
        self.add_subscription("coil_applied", Vector3Stamped, self._on_applied)
        self.add_service("run_control", RunControl, self._on_run_control)
        ref = self.scenario.reference
        self._network = bool(self.scenario.physics.vessel.network)
        if self._network:
            from vesselbot_ros.vessels.network import NetworkGeometry, load_network

            markers = cv.network_markers(NetworkGeometry(load_network(self.scenario.physics.vessel.network)),
                                         self.scenario.physics.robot.radius_m)
        else:
            markers = cv.vessel_markers(min(ref.anchors_x_m) - 1e-3, max(ref.anchors_x_m) + 1e-3,
                                        self.scenario.physics.vessel.diameter_m, self.scenario.physics.robot.radius_m)
        self.publish("vessel_markers", markers)
        self._rt_timer = None
        self._poll = self.create_timer(0.05, self._housekeeping, clock=self._wall)

    # ------------------------------------------------------------------ run control
    def _start(self) -> None:
        self.running = True
        self._wait_since = time.monotonic()
        self._emit()
        if not self.lockstep:
            self._wall_start = time.monotonic()
            self._anchor = self._wall_start
            self._rt_timer = self.create_timer(
                min(self.dt / self.graph.real_time_factor, 0.01), self._realtime_tick, clock=self._wall
            )

    def _on_run_control(self, req: Any, resp: Any) -> Any:
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
            resp.success = self.running and not self.finished and not self.lockstep
            self.paused = resp.success
            resp.message = "paused" if resp.success else "pause applies to a running real-time run only"
        elif c == RunControl.Request.RESUME:
            resp.success = self.paused
            if self.paused:
                self.paused = False
                self._wall_start = time.monotonic() - self.k * self.dt / self.graph.real_time_factor
                self._anchor = self._wall_start
            resp.message = "resumed" if resp.success else "not paused"
        elif c == RunControl.Request.STOP:
            self._finish()
            resp.message = "stopped"
        else:
            resp.message = "finished" if self.finished else ("running" if self.running else "waiting for START")
        resp.sim_time = self.k * self.dt
        resp.tick = self.k
        resp.finished = self.finished
        return resp

    def _housekeeping(self) -> None:
        if self.graph.autostart and not self.running and not self.finished and self.wired():
            self._start()
        if self.running and self.lockstep and not self.finished:
            waited = time.monotonic() - self._wait_since
            if waited > self.graph.plant_wait_warn_s:
                self._wait_since = time.monotonic()
                self.get_logger().warning(f"lockstep: still waiting for coil/applied of tick {self.k} ({waited:.1f} s)")

    # ------------------------------------------------------------------ ticks
    def _emit(self) -> None:
        """Publish /clock and truth for the current tick k."""
        self.tick_now = self.k
        out = self.plant.output(with_forces=True)
        self.publish("clock", cv.clock_msg(out.t_s))
        self.publish("truth", self._truth_msg(out))
        self.period_done(self.k)  # real time: tick k is due at wall start + k * dt / real_time_factor

    def _truth_msg(self, out: Any) -> PlantState:
        t = out.t_s
        r = self.scenario.physics.robot.radius_m
        x, z = float(out.p[0]), float(out.p[1])
        if self._network:
            s_t, _nx, _nz, d, _eta, vfx, vfz = network_geometry(t, x, z, self.plant.p)
            near, far = s_t - r, d - s_t - r  # gaps to the nearest wall and the opposite one
            gap_up, gap_lo = (near, far) if out.wall > 0 else (far, near)
        else:
            d = self._vessel.diameter(t)
            vfx, vfz = float(fluid_velocity_x(t, x, z, self.plant.p)), 0.0
            gap_up, gap_lo = 0.5 * d - z - r, z + 0.5 * d - r
        h = cv.header(t)
        f = out.forces
        fb = ForceBreakdown(header=h)
        for i, name in enumerate(("magnetic", "drag", "apparent_weight", "contact", "van_der_waals",
                                  "electrostatic", "steric", "total")):
            setattr(fb, name, cv.vector3(f[i]))
        return PlantState(
            header=h,
            tick=self.k,
            position=cv.point(out.p),
            velocity=cv.vector3(out.v),
            blood_velocity=cv.vector3((float(vfx), float(vfz))),
            vessel_diameter=float(d),
            wall_gap_upper=float(gap_up),
            wall_gap_lower=float(gap_lo),
            signed_wall_distance=out.delta_m,
            in_contact=out.in_contact,
            contact_phase=out.contact_phase,
            applied_gradient=cv.vector3(self._g),
            forces=fb,
        )

    def _advance(self, g: np.ndarray) -> None:
        self.plant.step(g)
        self._g = g
        self.k += 1
        self._wait_since = time.monotonic()
        if self.k >= self.n_ticks:
            self._finish()
        else:
            self._emit()

    def _finish(self) -> None:
        self.running = False
        if self._rt_timer is not None:
            self._rt_timer.cancel()
        self.mark_finished()

    def _on_applied(self, msg: Vector3Stamped) -> None:
        v = msg.vector
        if not self.check("coil_applied", frame_id=msg.header.frame_id, values=(v.x, v.y, v.z), y_values=(v.y,),
                          stamp_ns=None if self.lockstep else stamp_ns_of(msg)):
            return
        g = cv.xz(v)
        if not self.lockstep:
            self.count_received("coil_applied")
            self._g_latest = g
            return
        k, on_grid = cv.tick_of_ns(stamp_ns_of(msg), self.dt)
        if not on_grid:
            self.reject("coil_applied", "off_tick_stamp", f"stamp {stamp_ns_of(msg)} ns")
            return
        if not self.running or k != self.k:
            self.reject("coil_applied", "stale_tick" if k < self.k or not self.running else "future_tick",
                        f"tick {k}, plant at tick {self.k}")
            return
        self.count_received("coil_applied")
        self._advance(g)

    def _realtime_tick(self) -> None:
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

    def diagnostic_values(self) -> dict[str, str]:
        return {
            "tick": str(self.k),
            "sim_time_s": repr(self.k * self.dt),
            "n_ticks": str(self.n_ticks),
        } | {name: str(int(v)) for name, v in zip(PLANT_STAT_NAMES, self.plant.stats)}


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_plant``."""
    return run_node(PlantNode, argv)


if __name__ == "__main__":
    sys.exit(main())
