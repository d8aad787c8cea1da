"""Reference planner node: the C2 B-spline reference, as a path and per-tick samples.

Thin adapter over :class:`vesselbot_ros.control.bspline_reference.ReferenceTrajectory`,
built by :func:`vesselbot_ros.sim.closed_loop.build_stage`.

Ports (frame ``vessel``):

=================================  ================================  ==================  ================
port                               type                              rate                units
=================================  ================================  ==================  ================
in  ``/clock``                     rosgraph_msgs/Clock               per tick            s
out ``/vesselbot/reference``       vesselbot_msgs/ReferenceSample    per tick            m, m/s, m/s^2
out ``/vesselbot/reference/path``  nav_msgs/Path                     once (latched)      m
out ``/diagnostics``               diagnostic_msgs/DiagnosticArray   1 Hz wall           counts
=================================  ================================  ==================  ================

On ``/clock`` = t_k it publishes sample k (stamp t_k, ``tick`` = k).  The
samples of ticks 0..n-1 are computed once with ``sample_many`` over the
runner's own time grid (bit-identical to the pure runner); off-grid clock
times (a user's clock) are sampled with ``sample(t)``.

Input checks: a ``/clock`` time that is negative or not newer than the last
one is rejected (WARN diagnostics).
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from nav_msgs.msg import Path
from rosgraph_msgs.msg import Clock
from vesselbot_msgs.msg import ReferenceSample

from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.base import VesselbotNode
from vesselbot_ros.nodes.process import run_node
from vesselbot_ros.sim.closed_loop import build_stage

__all__ = ["ReferenceNode", "main"]


class ReferenceNode(VesselbotNode):
    """The reference planner (see module docstring)."""

    ROLE = "reference"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.ROLE, **kwargs)
        self.reference = build_stage(self.scenario, self.stage)
        ts = np.arange(self.n_ticks) * self.dt
        self._p, self._v, self._a = self.reference.sample_many(ts)
        self.reset_state()
        self.add_publisher("reference", ReferenceSample)
        self.add_publisher("reference_path", Path)
        self.add_subscription("clock", Clock, self._on_clock)
        self.publish("reference_path", cv.path_msg(self.reference.path(200)))
        self.realtime_clock()

    def reset_state(self) -> None:
        """Back to t = 0 (the reference itself is a pure function of time)."""
        self._last_ns = -1

    def _on_clock(self, msg: Any) -> None:
        """``/clock``, in its flat form (``clock_sec``, ``clock_nanosec``)."""
        if not self.lockstep:
            k = self.accept_clock(msg)  # real time: a garbage /clock moves nothing
            if k is not None and k < self.n_ticks:
                self.publish("reference", cv.reference_flat(k, cv.tick_time(k, self.dt), self._p[k], self._v[k],
                                                            self._a[k], self.dims))
                self.period_done(k)
            return
        ns = msg.clock_sec * cv.NS_PER_S + msg.clock_nanosec  # flat form
        if ns <= self._last_ns:
            self.reject("clock", "stale_stamp", f"clock {ns} ns not newer than {self._last_ns} ns")
            return
        self._last_ns = ns
        self.count_received("clock")
        k, on_grid = cv.tick_of_ns(ns, self.dt)
        if on_grid and 0 <= k < self.n_ticks:
            t = cv.tick_time(k, self.dt)
            self.publish("reference", cv.reference_flat(k, t, self._p[k], self._v[k], self._a[k], self.dims))
            self.period_done(k)
            if k + 1 >= self.n_ticks:
                self.mark_finished()
        elif on_grid:
            s = self.reference.sample(ns * 1e-9)
            self.publish("reference", cv.reference_flat(k, ns * 1e-9, s.p, s.v, s.a, self.dims))


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_reference``."""
    return run_node(ReferenceNode, argv, exit_process=True)


if __name__ == "__main__":
    sys.exit(main())
