"""Plans the scanner can fly: a reference re-timed and re-placed so that the coil can hold it (``vesselbot plan``).

The scanner study's hold margin (:mod:`vesselbot_ros.analysis.scanner_study`)
says whether the coil, on average over the sequence, gives the acceleration a
reference needs.  The planner turns that bound into a reference:

* **Budget.**  Over a period, the coil gives ``a_avail = duty * a_sat``
  (``a_sat``: the acceleration of the saturated gradient, eq. (2)).  The
  acceleration a reference point needs is ``|Xdd_ref - F(t, X_ref, Xd_ref)|``
  with the true plant's ``F`` (drag of the flow with the wall effect, the
  apparent weight, the wall's interaction forces) -- except on the lower
  wall, which carries any push into it: there the upward share of the need
  is the wall's (the contact's normal force), and the coil supplies the rest.
* **Where in the lumen.**  Along the path (anchors every ``anchor_spacing_m``)
  each anchor takes the height with the least need over a cardiac period:
  ``free_heights`` heights across the free lumen, or resting on the lower
  wall (the reference then follows the wall's pulsation,
  ``reference.wall_follow``), where the wall carries the weight and the blood
  is slowest.  The first anchor stays where the scenario starts.  In a vessel
  network the route's own anchors are kept (heights are not re-placed).
* **When.**  A forward pass in steps of ``step_s`` takes, at each step, the
  largest path speed (up to ``max_speed_m_per_s``, with a tangential
  acceleration within ``tangential_accel_m_per_s2`` and a stop at the end)
  whose need stays within ``budget_fraction * a_avail``: it advances where and
  when the flow allows (diastole, near a wall) and holds where it does not
  (systole).  It never stops on a crest of the floor it rests on (:func:`_crests`: an up-slope that tops
  out and falls away, as a side branch's mouth seen from its parent's floor), where a bead held slips onto the
  far slope and the nearest wall flips between the two faces: short of one it looks ahead and crosses only when
  a pass within ``crest_budget_share`` of the budget gets over it without stopping, else it waits there
  (at most a cardiac period).  The speed is then smoothed (a Hann window of ``smooth_s``) and
  tabulated every ``table_step_s`` (``reference.timing: planned``, a C2 spline).
* **Checked.**  The planned reference is sampled every ``step_s`` and every
  segment (between two anchors) gets its margin ``a_avail - max need`` and its
  coast floor (half the largest drift from the reference over one coast,
  released on the reference with no gradient: the plant's own integrator, so
  a bead on the wall coasts on the wall; coasts start every
  ``coast_every_s``, or every quarter coast when a coast is longer than four
  of those, so that the check's work does not grow with the tracking window;
  its plant time is estimated before it starts and a check over
  :data:`COAST_BUDGET_PLANT_S` is refused in one line naming
  ``sequence.tracking_window_s``).  A negative margin makes the pass
  run again with a budget fraction 0.85 times smaller (at most
  ``retries`` times); still negative: :class:`PlanInfeasible`, which names the
  segment and the acceleration missing.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.analysis.meshed_wall import MeshedWall, need_on
from vesselbot_ros.blas_free import convolve_valid
from vesselbot_ros.config import ConfigError, check_choice, check_positive, check_range
from vesselbot_ros.control.bspline_reference import ReferenceParams, ReferenceTrajectory, WallMotion, wall_shift_of
from vesselbot_ros.control.model import BLOOD_VELOCITY_ERROR, DynamicsModel
from vesselbot_ros.control.route import planned_reference
from vesselbot_ros.errors import ModelInputError, VesselbotError
from vesselbot_ros.physics.axes import AXES
from vesselbot_ros.physics.kernel import diameter_at
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.progress import step
from vesselbot_ros.scanner.input_mapping import input_matrix
from vesselbot_ros.scanner.sequence import duty_cycle
from vesselbot_ros.sim.closed_loop import build_stages
from vesselbot_ros.sim.scenario import Scenario, scenario_from_mapping
from vesselbot_ros.vessels.cfd import packed_params

__all__ = ["COAST_BUDGET_PLANT_S", "COAST_STARTS_PER_COAST", "check_fits_path",
           "PlanOptions", "PlanInfeasible", "Segment", "Plan", "available_accel", "need", "wall_rest", "make_plan",
           "flying_changes", "WALL_FLOW_SCALE_SIGMA0", "CREST_RESTARTS",
           "evaluate", "plan_scenario", "coast_time_s", "reachable", "crest_times"]


#: Coast starts per coast length at most: a longer coast (a long tracking window) starts a quarter coast apart, not
#: every ``coast_every_s`` (so the check's plant time grows with the plan's duration, not with the window).
COAST_STARTS_PER_COAST = 4
#: The most plant time (s) one check of a plan (:func:`evaluate`) may integrate for its coast floors (a bead resting
#: on the wall integrates at about 0.1 s of wall time per second of plant time; the shipped plans need 2-15 s).
COAST_BUDGET_PLANT_S = 120.0


class PlanInfeasible(VesselbotError):
    """No reference along this path is within the coil's budget: names the segment and the acceleration missing."""

    def __init__(self, message: str, segment: Segment | None = None, missing_m_per_s2: float = math.inf) -> None:
        super().__init__(message)
        self.segment, self.missing_m_per_s2 = segment, missing_m_per_s2


@dataclasses.dataclass(frozen=True)
class PlanOptions:
    """How the planner searches (module docstring)."""

    budget_fraction: float = 0.8
    free_heights: int = 9
    height: str = "auto"
    anchor_spacing_m: float = 1.0e-3
    floor_anchor_spacing_m: float = 0.0
    step_s: float = 1.0e-3
    check_step_s: float = 2.5e-4
    smooth_s: float = 0.02
    table_step_s: float = 0.005
    max_speed_m_per_s: float = 0.0
    max_path_speed_m_per_s: float = 0.05
    tangential_accel_m_per_s2: float = 0.5
    wall_press_m: float = 25e-6
    wall_clearance_m: float = 50e-6
    landing_s: float = 0.01
    slide_s: float = 0.08
    max_duration_s: float = 60.0
    coast_every_s: float = 0.01
    retries: int = 4
    crest_budget_share: float = 0.85

    def __post_init__(self) -> None:
        check_range("budget_fraction", self.budget_fraction, 0.05, 1.0)
        check_choice("height", self.height, ("auto", "free", "wall"))
        check_range("free_heights", self.free_heights, 1, 101)
        for name in ("check_step_s", "anchor_spacing_m", "wall_clearance_m", "max_path_speed_m_per_s", "slide_s",
                     "landing_s", "step_s", "smooth_s", "table_step_s", "tangential_accel_m_per_s2",
                     "max_duration_s", "coast_every_s"):
            check_positive(name, getattr(self, name))
        if not (math.isfinite(self.wall_press_m) and 0.0 <= self.wall_press_m <= 1e-4):
            raise ConfigError(f"wall_press_m must be in [0, 1e-4] m, got {self.wall_press_m!r}")
        if not (math.isfinite(self.floor_anchor_spacing_m) and self.floor_anchor_spacing_m >= 0.0):
            raise ConfigError(f"floor_anchor_spacing_m must be >= 0 m (0: half anchor_spacing_m), "
                              f"got {self.floor_anchor_spacing_m!r}")
        if not (math.isfinite(self.max_speed_m_per_s) and self.max_speed_m_per_s >= 0.0):
            raise ConfigError(f"max_speed_m_per_s must be >= 0 (0: the scenario's own speed), "
                              f"got {self.max_speed_m_per_s!r}")
        check_range("retries", self.retries, 0, 20)
        check_range("crest_budget_share", self.crest_budget_share, 0.05, 1.0)
        if self.table_step_s < self.step_s:
            raise ConfigError(f"table_step_s must be >= step_s ({self.step_s!r}), got {self.table_step_s!r}")


@dataclasses.dataclass(frozen=True)
class Segment:
    """One stretch of the plan: ``anchor_spacing_m`` of its path parameter (:func:`evaluate`)."""

    index: int
    x_from_m: float
    x_to_m: float
    mode: str  # "wall" (every sample on the lower wall), "free" (none) or "mixed"
    height_m: float  # mean lateral position (z) over the segment
    t_from_s: float
    t_to_s: float
    need_m_per_s2: float  # the largest need along the segment
    t_worst_s: float
    margin_m_per_s2: float  # a_avail - need
    coast_floor_m: float

    def describe(self, n: int) -> str:
        where = {"wall": "on the lower wall", "free": f"at z = {self.height_m * 1e3:+.2f} mm",
                 "mixed": "partly on the lower wall"}[self.mode]
        return f"segment {self.index + 1} of {n} (x {self.x_from_m * 1e3:.1f}-{self.x_to_m * 1e3:.1f} mm, {where})"


@dataclasses.dataclass(frozen=True)
class Plan:
    """A planned reference and its margins."""

    reference: ReferenceParams
    segments: tuple[Segment, ...]
    a_avail_m_per_s2: float
    a_sat_m_per_s2: float
    duty: float
    budget_fraction: float
    end_s: float
    #: The stretches of the path parameter (m) round each crest of the floor the route rests on (:func:`_crests`).
    crests: tuple[tuple[float, float], ...] = ()

    @property
    def margin_m_per_s2(self) -> float:
        return min(s.margin_m_per_s2 for s in self.segments)

    @property
    def coast_floor_m(self) -> float:
        return max(s.coast_floor_m for s in self.segments)


def coil_gain(physics: PhysicsParams) -> float:
    """``|b|`` (m/s^2 per T/m): the acceleration 1 T/m gives the bead on the vertical axis, on any axes (the input
    matrix reads the bead only: a 3-D tree's is ``b I`` with the same ``b``, as
    :class:`~vesselbot_ros.control.model.DynamicsModel`)."""
    return abs(float(input_matrix(physics)[1, 1]))


def available_accel(scenario: Scenario) -> tuple[float, float, float]:
    """``(a_avail, a_sat, duty)``: the duty-averaged acceleration the saturated coil gives (m/s^2)."""
    a_sat = coil_gain(scenario.physics) * scenario.coil.saturation_T_per_m
    duty = duty_cycle(scenario.sequence)
    return duty * a_sat, a_sat, duty


def coast_time_s(scenario: Scenario) -> float:
    """How long the bead coasts between two propulsion windows (s): 0 with continuous propulsion."""
    seq = scenario.sequence
    return 0.0 if seq.mode == "continuous" else seq.tracking_window_s + 2.0 * seq.dead_time_s


Rest = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | MeshedWall | None


def need(model: DynamicsModel, t: npt.ArrayLike, p: npt.ArrayLike, v: npt.ArrayLike, a: npt.ArrayLike,
         rest: Rest = None, resting: npt.NDArray[np.bool_] | None = None) -> npt.NDArray[np.float64]:
    """The coil's acceleration each point needs (m/s^2): ``|a - F(t, p, v)|``, the lower wall's share removed.

    ``rest``: ``(z, dz/dt)`` of a bead resting on the lower wall at each
    point's time (:func:`wall_rest`).  A point at or below it is a bead on
    the wall: it is evaluated there, moving with the wall, and the contact
    supplies any upward push (the vertical component of ``a - F`` counts only
    when it points down).  In a network or a tree ``rest`` is its
    :class:`~vesselbot_ros.analysis.meshed_wall.MeshedWall`: a point within
    ``r + L0`` of its wall (or beyond) rests on it, moving with it, and the
    contact carries any push along the wall's inward normal; ``resting``:
    the points meant to rest on it (:meth:`MeshedWall.snap`).
    """
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    p, v, a = (np.atleast_2d(np.asarray(x, dtype=np.float64)).copy() for x in (p, v, a))
    if isinstance(rest, MeshedWall):
        return need_on(model.F, t, rest.snap(t, p, v, resting), a)
    wall = np.zeros(t.shape, dtype=bool)
    if rest is not None:
        z_rest, vz_rest = (np.broadcast_to(np.asarray(x, dtype=np.float64), t.shape) for x in rest)
        wall = p[:, 1] <= z_rest + 1e-9
        p[wall, 1] = z_rest[wall]
        v[wall, 1] = vz_rest[wall]
    out = np.empty(t.shape)
    for k in range(t.size):
        f = model.F(float(t[k]), p[k], v[k])
        if p.shape[1] != 2:  # axis count: a 3-D tree (no lower wall to rest on: rest is the straight vessel's)
            out[k] = math.hypot(*(a[k] - f))
            continue
        dx, dz = a[k, 0] - f[0], a[k, 1] - f[1]
        if wall[k] and dz > 0.0:
            dz = 0.0
        out[k] = math.hypot(dx, dz)
    return out


def wall_rest(scenario: Scenario, t: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
    """``(z, dz/dt)`` of a bead resting on the straight vessel's lower wall at times ``t``; ``None`` in a network."""
    shift = wall_shift_of(scenario.physics)
    if shift is None:
        return None
    h, hd, _ = shift(np.atleast_1d(np.asarray(t, dtype=np.float64)))
    return _resting_z(scenario) - h, -hd


def rest_of(scenario: Scenario, wall: MeshedWall | None, t: npt.ArrayLike) -> Rest:
    """What :func:`need` takes as ``rest`` at times ``t``: the straight vessel's lower wall (:func:`wall_rest`), or
    a network's or a tree's meshed wall (``wall``, built once: :func:`meshed_wall`)."""
    return wall if wall is not None else wall_rest(scenario, t)


def meshed_wall(scenario: Scenario) -> MeshedWall | None:
    """The meshed wall of a network or a tree the planner rests a bead on; ``None`` in the straight vessel."""
    return MeshedWall(scenario) if scenario.physics.vessel.network else None


def _resting(traj: ReferenceTrajectory, u: npt.NDArray[np.float64],
             wall: MeshedWall | None) -> npt.NDArray[np.bool_] | None:
    """Which points of a network's reference are meant to rest on its floor (wall-follow weight 1); ``None`` in the
    straight vessel."""
    return None if wall is None else traj.follow_weight(u)[0] >= 1.0 - 1e-9


def needs_on_wall(scenario: Scenario, model: DynamicsModel, wall: MeshedWall | None, t: npt.NDArray[np.float64],
                  p: npt.NDArray[np.float64], v: npt.NDArray[np.float64], a: npt.NDArray[np.float64],
                  resting: npt.NDArray[np.bool_] | None = None) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """:func:`need` at each point of a reference, and which points rest on the wall (the straight vessel's lower
    wall, a network's floor): the wall found once for both."""
    if wall is not None:
        snapped = wall.snap(t, p, v, resting)
        return need_on(model.F, t, snapped, a), snapped.on_wall
    rest = wall_rest(scenario, t)
    on_wall = np.zeros(t.shape, dtype=bool) if rest is None else p[:, 1] <= rest[0] + 1e-9
    return need(model, t, p, v, a, rest), on_wall


# ---------------------------------------------------------------------------------------------- geometry
def _resting_z(scenario: Scenario) -> float:
    """z of the bead's centre resting on the lower wall of the nominal vessel (m): one brush length of gap."""
    ph = scenario.physics
    return -(0.5 * ph.vessel.diameter_m - ph.robot.radius_m - ph.interactions.brush_length_m)


def _pressed_z(scenario: Scenario, options: PlanOptions) -> float:
    """z of a reference that rides the lower wall: ``wall_press_m`` into it, so that its spline never lifts off."""
    return _resting_z(scenario) - options.wall_press_m


@dataclasses.dataclass(frozen=True)
class _Fall:
    """The bead released at the start with no gradient, until it rests on the lower wall (1 ms samples)."""

    t: npt.NDArray[np.float64]
    p: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]


def _fall(scenario: Scenario, t0: float, p0: npt.NDArray[np.float64], step_s: float, x_end: float,
          options: PlanOptions, wall: MeshedWall | None = None) -> tuple[_Fall, int] | None:
    """The fall from ``p0`` at rest to the lower wall with no gradient, then sliding on it for ``slide_s``; and the
    sample where it touched.  ``None`` if it passes ``x_end`` first (1 s at most).

    The bead hits the wall at its sinking speed (no coil within the budget
    could slow it: the drag keeps it near its terminal speed), and the wall
    stops it at once.  A smooth reference cannot turn that sharply, so after
    the touch (the last sample before it hits the wall, ``g0`` above it) the
    reference dips into the wall and comes back: ``z = rest + g0 (1 - S) -
    press S - v_s tau exp(-(tau / T)^2)`` with ``S = S(tau / T)`` the quintic
    smoothstep (``T = landing_s``, ``v_s`` the sinking speed at the touch; at
    most ``0.43 v_s T`` deep): continuous in position, velocity and
    acceleration at the touch, and every upward acceleration of the landing
    inside the wall, which carries it.  The plant's bead bounces on the wall
    after it; the reference does not.  On a network's or a tree's floor
    (``wall``) the same, along the wall's inward normal ``n`` at each sample:
    ``p = q + n (g0 (1 - S) - press S - v_s tau exp(-(tau / T)^2))`` with ``q``
    the bead's point moved onto the resting surface.
    """
    if wall is not None:
        return _fall_meshed(scenario, t0, p0, step_s, options, wall)
    plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
    y = np.array([p0[0], p0[1], 0.0, 0.0])
    contact = plant.new_contact_state()
    t, ts, ps, vs = t0, [t0], [y[:2].copy()], [y[2:].copy()]
    touched, v_s, g0 = -1, 0.0, 0.0
    T = options.landing_s
    for _ in range(int(round((1.0 + options.slide_s) / step_s))):
        plant.propagate(t, t + step_s, y, np.zeros(2), contact)
        t += step_s
        if y[0] > x_end:
            return None
        rest = wall_rest(scenario, t)
        assert rest is not None
        z_rest, vz_rest = rest[0][0], rest[1][0]
        gap, sink = y[1] - z_rest, vz_rest - y[3]
        if touched < 0 and gap <= 2e-6 + max(sink, 0.0) * step_s:
            # it hits the wall within the next step (the plant's bead then bounces on it, which no smooth
            # reference follows): the reference lands from here, from where the bead is and as fast as it sinks
            touched, v_s, g0 = len(ts), max(sink, 0.0), max(gap, 0.0)
        ts.append(t)
        if touched >= 0:
            tau = t - ts[touched]
            S, dip = _landing(tau, T)
            z = z_rest + g0 * (1.0 - S) - options.wall_press_m * S - v_s * tau * dip
            ps.append(np.array([y[0], z]))
            vs.append(np.array([y[2], vz_rest]))
            if tau >= options.slide_s - 1e-12:
                return _Fall(np.asarray(ts), np.asarray(ps), np.asarray(vs)), touched
        else:
            ps.append(y[:2].copy())
            vs.append(y[2:].copy())
    return None


def _landing(tau: float, T: float) -> tuple[float, float]:
    """The landing's quintic smoothstep ``S(tau / T)`` and its dip's factor ``exp(-(tau / T)^2)`` (:func:`_fall`)."""
    s = min(tau / T, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2), math.exp(-((tau / T) ** 2))


def _fall_meshed(scenario: Scenario, t0: float, p0: npt.NDArray[np.float64], step_s: float, options: PlanOptions,
                 wall: MeshedWall) -> tuple[_Fall, int] | None:
    """:func:`_fall` onto a network's or a tree's floor (1 s at most)."""
    plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
    d = plant.dims
    y = np.concatenate([np.asarray(p0, dtype=np.float64), np.zeros(d)])
    contact = plant.new_contact_state()
    t, ts, ps, vs = t0, [t0], [y[:d].copy()], [y[d:].copy()]
    touched, v_s, g0 = -1, 0.0, 0.0
    T = options.landing_s
    for _ in range(int(round((1.0 + options.slide_s) / step_s))):
        plant.propagate(t, t + step_s, y, np.zeros(d), contact)
        t += step_s
        s, n, d_t = wall.frames(t, y[:d])
        n = n[0]
        e, de = wall.eps(np.array([t]))
        wall_speed = float(-0.5 * d_t[0] / (1.0 + e[0]) * de[0])  # the wall's velocity along n
        v_n = float((y[d:] * n).sum())
        gap, sink = float(s[0]) - wall.gap_m, wall_speed - v_n
        if touched < 0 and gap <= 2e-6 + max(sink, 0.0) * step_s:
            touched, v_s, g0 = len(ts), max(sink, 0.0), max(gap, 0.0)
        ts.append(t)
        if touched >= 0:
            tau = t - ts[touched]
            S, dip = _landing(tau, T)
            q = y[:d] - gap * n  # the bead's point on the resting surface
            ps.append(q + n * (g0 * (1.0 - S) - options.wall_press_m * S - v_s * tau * dip))
            vs.append(y[d:] + (wall_speed - v_n) * n)
            if tau >= options.slide_s - 1e-12:
                return _Fall(np.asarray(ts), np.asarray(ps), np.asarray(vs)), touched
        else:
            ps.append(y[:d].copy())
            vs.append(y[d:].copy())
    return None


def _phases(scenario: Scenario) -> npt.NDArray[np.float64]:
    """48 times over one cardiac period (s): where a height is judged at every phase of the flow and the wall."""
    return np.linspace(0.0, 2.0 * math.pi / scenario.physics.flow.angular_frequency_rad_per_s, 48, endpoint=False)


def _heights(scenario: Scenario, options: PlanOptions) -> list[tuple[float, bool]]:
    """Candidate heights ``(z, on the wall)``: across the free lumen at its narrowest (``wall_clearance_m`` from
    either wall), and resting on the lower wall."""
    ph = scenario.physics
    p_pack = packed_params(ph)
    d_min = min(float(diameter_at(float(t), p_pack)) for t in _phases(scenario))
    z_free = 0.5 * d_min - ph.robot.radius_m - options.wall_clearance_m
    out: list[tuple[float, bool]] = []
    if options.free_heights == 1 or z_free <= 0.0:
        out.append((0.0, False))
    else:
        out += [(float(z), False) for z in np.linspace(-z_free, z_free, options.free_heights)]
    if options.height != "free":
        out.append((_pressed_z(scenario, options), True))
    return out


def _best_height(scenario: Scenario, model: DynamicsModel, x: float, heights: list[tuple[float, bool]],
                 v_cap: float) -> tuple[float, bool]:
    """The height with the least need at ``x``: at each phase the least over a few speeds, the worst phase."""
    phases = _phases(scenario)
    rest = wall_rest(scenario, phases)
    assert rest is not None
    best = (math.inf, 0.0, False)
    for z, on_wall in heights:
        p = np.column_stack([np.full_like(phases, x), rest[0] if on_wall else np.full_like(phases, z)])
        per_speed = [need(model, phases, p, np.column_stack([np.full_like(phases, speed), np.zeros_like(phases)]),
                          np.zeros_like(p), rest) for speed in (0.0, 0.5 * v_cap, v_cap)]
        worst = float(np.max(np.min(per_speed, axis=0)))
        if worst < best[0] - 1e-12:
            best = (worst, z, on_wall)
    return best[1], best[2]


@dataclasses.dataclass(frozen=True)
class _Geometry:
    anchors: npt.NDArray[np.float64]  # (k, 2)
    follow: npt.NDArray[np.float64]  # (k,)
    fall: _Fall | None  # the path's first anchors are the fall's, flown at the fall's own timing
    fall_picks: tuple[int, ...]  # the fall's samples that are anchors (the last one rests on the wall)


def _geometry(scenario: Scenario, model: DynamicsModel, options: PlanOptions, v_cap: float) -> _Geometry:
    """Anchors, wall-follow weights and the fall to the wall if any (module docstring: where in the lumen)."""
    ref = planned_reference(scenario)
    first = np.array([ref.anchors_x_m[0], ref.anchors_z_m[0]])
    if scenario.physics.vessel.network:  # a route: its own anchors, or the floor below them, on the network's axes
        return _net_geometry(scenario, model, options, v_cap)
    x0, x1 = float(ref.anchors_x_m[0]), float(ref.anchors_x_m[-1])
    heights = _heights(scenario, options)
    _, wall_next = _best_height(scenario, model, min(x1, x0 + options.anchor_spacing_m), heights, v_cap)
    if wall_next:  # sink to the wall as the bead falls by itself: no gradient needed on the way down
        got = _fall(scenario, float(ref.start_s), first, options.step_s, x1 - 0.5 * options.anchor_spacing_m, options)
        if got is not None and got[0].p[-1, 0] - got[0].p[0, 0] < 0.25 * options.anchor_spacing_m:
            got = None  # it falls (or rests) about where it starts: the path starts on the wall below it instead
        if got is not None:
            fall, touched = got
            picks = _fall_picks(fall, touched, options)
            x_last = float(fall.p[-1, 0])
            n = max(1, int(math.ceil((x1 - x_last) / options.anchor_spacing_m - 1e-9)))
            xs = np.linspace(x_last, x1, n + 1)[1:]
            # every anchor follows the wall (weight 1), so the fall's anchors are given in the nominal vessel: the
            # reference passes each at its time in the fall, when the wall has moved down by h(t); from the
            # landing on, pressed into the wall
            h, _, _ = wall_shift_of(scenario.physics)(fall.t[list(picks)])  # type: ignore[misc]  # straight vessel
            landed = fall.p[picks] + np.column_stack([np.zeros(len(picks)), h])
            anchors = np.vstack([landed, np.column_stack([xs, np.full_like(xs, _pressed_z(scenario, options))])])
            follow = np.ones(len(picks) + len(xs))
            return _Geometry(anchors, follow, dataclasses.replace(fall, t=fall.t - fall.t[0]), tuple(picks))
    n = max(2, int(math.ceil((x1 - x0) / options.anchor_spacing_m - 1e-9)) + 1)
    xs = np.linspace(x0, x1, n)
    # the first anchor after the start comes soon: the bead changes height before it advances
    xs = np.concatenate([[x0, x0 + min(0.25 * options.anchor_spacing_m, 0.5 * (xs[1] - x0))], xs[1:]])
    zs, weights = [float(first[1])], [0.0]
    for x in xs[1:]:
        z, on_wall = _best_height(scenario, model, float(x), heights, v_cap)
        zs.append(z)
        weights.append(1.0 if on_wall else 0.0)
    rest = wall_rest(scenario, float(ref.start_s))  # a straight vessel here: a network returned above
    if weights[1] == 1.0 and rest is not None and first[1] <= rest[0][0] + 5e-6:
        zs[0], weights[0] = zs[1], 1.0  # it starts on the wall: the path rides it from the start
    return _Geometry(np.column_stack([xs, zs]), np.asarray(weights), None, ())


def _arc(points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Cumulative arc length along points (n, d) (m); the plane's through ``np.hypot`` (its bits)."""
    d = np.diff(points, axis=0)
    step_len = np.hypot(*d.T) if points.shape[1] == 2 else np.sqrt((d * d).sum(axis=1))
    return np.concatenate([[0.0], np.cumsum(step_len)])


def _net_need(scenario: Scenario, model: DynamicsModel, wall: MeshedWall, q: npt.NDArray[np.float64],
              tangent: npt.NDArray[np.float64], v_cap: float, on_wall: bool) -> float:
    """The worst need over a cardiac period at anchor ``q`` (on the still wall's floor if ``on_wall``, then moving
    with the wall), at each phase the least over a few speeds along ``tangent``."""
    phases = _phases(scenario)
    p = np.repeat(q[None, :], phases.size, axis=0)
    if on_wall:
        p -= wall.eps(phases)[0][:, None] * wall.follow_offset(q[None, :])
    resting = np.full(phases.shape, on_wall)
    per_speed = [need(model, phases, p, np.repeat(speed * tangent[None, :], phases.size, axis=0), np.zeros_like(p),
                      wall, resting) for speed in (0.0, 0.5 * v_cap, v_cap)]
    return float(np.max(np.min(per_speed, axis=0)))


def _net_geometry(scenario: Scenario, model: DynamicsModel, options: PlanOptions, v_cap: float) -> _Geometry:
    """A network's or a tree's route: its own anchors (``height: free``), or points along it every
    ``floor_anchor_spacing_m`` (0: half ``anchor_spacing_m``), each on the route or on the floor below it, whichever
    needs less.  The cubic through anchors on the floor cuts a crest of it between them: at half a millimetre, the
    external carotid's ridge by up to 90 um into the wall, where no bead can be (docs/reproduction.md); every
    0.125 mm it hugs the ridge.  A route whose first
    anchor on the floor follows a start in the free lumen begins with the bead's own fall to the floor
    (:func:`_fall`).  Where the floor between two anchors on it breaks off (a side branch's mouth, a junction's
    floor falling away) the bead would cross off the wall: :class:`PlanInfeasible` if the coil cannot hold it there
    (:func:`_check_floor`)."""
    ref = planned_reference(scenario)
    if options.height == "free":
        return _Geometry(ref.anchor_points(), np.zeros(len(ref.anchors_x_m)), None, ())
    route = ReferenceTrajectory(ref)
    spacing = options.floor_anchor_spacing_m or 0.5 * options.anchor_spacing_m
    n = max(2, int(math.ceil(route.length_m / spacing - 1e-9)) + 1)
    us = np.linspace(0.0, route.length_m, n)
    pts = np.asarray(route.path(n)) if n >= 2 else np.asarray([route.path_point(0.0)])
    follow = np.zeros(len(pts))
    wall = MeshedWall(scenario)
    d1 = np.gradient(pts, axis=0)
    tangents = d1 / np.maximum(np.sqrt((d1 * d1).sum(axis=1)), 1e-12)[:, None]
    anchors = pts.copy()
    # a hole is judged against the floor over the same length of route whatever the spacing (2.5 mm each side)
    floors = _regular_floors(pts, [wall.floor_below(p, options.wall_press_m) for p in pts],
                             scenario.physics.robot.radius_m,
                             max(5, int(round(FLOOR_FIT_HALF_WINDOW_M / spacing))))
    for k in range(1, len(pts)):
        floor = floors[k]
        if floor is None:
            continue
        if (_net_need(scenario, model, wall, floor, tangents[k], v_cap, True)
                < _net_need(scenario, model, wall, pts[k], tangents[k], v_cap, False) - 1e-12):
            anchors[k], follow[k] = floor, 1.0
    _cross_breaks(scenario, model, wall, pts, anchors, follow, tangents, v_cap)
    _check_floor(scenario, model, wall, route, us, anchors, follow, tangents, v_cap, options)
    if follow[1] != 1.0:
        return _Geometry(anchors, follow, None, ())
    s0, _, _ = wall.frames(float(ref.start_s), pts[0])
    if s0[0] <= wall.gap_m + 5e-6:  # it starts on the floor: the path rides it from the start, pressed into it
        _, n0, _ = wall.frames(float(ref.start_s), pts[0])
        e0 = float(wall.eps(np.array([float(ref.start_s)]))[0][0])
        anchors[0] = pts[0] - options.wall_press_m * n0[0] + e0 * wall.follow_offset(pts[0])[0]
        follow[0] = 1.0
        return _Geometry(anchors, follow, None, ())
    arc = _arc(pts)
    got = _fall(scenario, float(ref.start_s), pts[0], options.step_s, math.inf, options, wall)
    if got is None:
        return _Geometry(anchors, follow, None, ())
    fall, touched = got
    # where the fall lands along the route: the point of the route's polyline nearest the landing across the
    # vertical (the floor lies below the route: its horizontal axes are the route's)
    land = fall.p[-1]
    seg_d = np.diff(pts, axis=0)
    flat = np.ones(pts.shape[1])
    flat[-1] = 0.0
    lam = np.clip(((land - pts[:-1]) * seg_d * flat).sum(axis=1)
                  / np.maximum((seg_d * seg_d * flat).sum(axis=1), 1e-30), 0.0, 1.0)
    near = pts[:-1] + lam[:, None] * seg_d
    j = int(np.argmin((((near - land) * flat) ** 2).sum(axis=1)))
    arc_land = float(arc[j] + lam[j] * (arc[j + 1] - arc[j]))
    if arc_land > arc[-1] - options.anchor_spacing_m:
        return _Geometry(anchors, follow, None, ())  # it falls nearly to the end: no room to land and fly on
    floor_there = wall.floor_below(near[j], options.wall_press_m)
    _, _, d_there = wall.frames(0.0, near[j], still=True)
    if floor_there is None or float(np.sqrt(((floor_there - land) ** 2).sum())) > 0.2 * float(d_there[0]):
        return _Geometry(anchors, follow, None, ())  # it lands off the route's floor (in a side branch's mouth)
    picks = _fall_picks(fall, touched, options)
    keep = np.flatnonzero(arc > arc_land + 0.5 * options.anchor_spacing_m)
    # every fall anchor follows the floor below it (weight 1, as in the straight vessel), so the anchors are given
    # on the still wall's frame: the reference passes each at its time in the fall, when the floor below has moved
    # by -eps(t) D n / 2 (the anchor's own offset: found from the sample's in two passes)
    tp = fall.t[list(picks)]
    eps = wall.eps(tp)[0][:, None]
    landed = fall.p[picks] + eps * wall.follow_offset(fall.p[picks])
    landed = fall.p[picks] + eps * wall.follow_offset(landed)
    weights = np.ones(len(picks))
    anchors = np.vstack([landed, anchors[keep]])
    follow = np.concatenate([weights, follow[keep]])
    return _Geometry(anchors, follow, dataclasses.replace(fall, t=fall.t - fall.t[0]), tuple(picks))


#: The length of route (m) each side of a point over which :func:`_regular_floors` fits the floor's line.
FLOOR_FIT_HALF_WINDOW_M = 2.5e-3


def _regular_floors(pts: npt.NDArray[np.float64], floors: list[npt.NDArray[np.float64] | None],
                    radius_m: float, half_window: int = 5) -> list[npt.NDArray[np.float64] | None]:
    """The floors below the route's points, a hole in the floor (a side branch's mouth: the floor more than half a
    bead radius below the straight line fitted to its neighbours' heights within ``half_window`` points, holes
    left out of the fit) made
    ``None``: the bead would drop into it, not ride over it."""
    height = np.array([np.nan if f is None else float(f[-1]) for f in floors])
    hole = ~np.isfinite(height)
    for _ in range(3):  # fit, flag what lies below the fit, fit again without it
        flagged = hole.copy()
        for k in range(len(pts)):
            lo, hi = max(0, k - half_window), min(len(pts), k + half_window + 1)
            idx = np.arange(lo, hi)
            idx = idx[(idx != k) & ~hole[lo:hi]]
            if idx.size < 2 or not np.isfinite(height[k]):
                continue
            x, y = idx.astype(np.float64), height[idx]
            xm, ym = x.mean(), y.mean()
            sxx = float(((x - xm) ** 2).sum())
            slope = float(((x - xm) * (y - ym)).sum()) / sxx if sxx > 0.0 else 0.0
            if height[k] < ym + slope * (k - xm) - 0.5 * radius_m:
                flagged[k] = True
        if np.array_equal(flagged, hole):
            break
        hole = flagged
    return [None if hole[k] else floors[k] for k in range(len(pts))]


def _cross_breaks(scenario: Scenario, model: DynamicsModel, wall: MeshedWall, pts: npt.NDArray[np.float64],
                  anchors: npt.NDArray[np.float64], follow: npt.NDArray[np.float64],
                  tangents: npt.NDArray[np.float64], v_cap: float) -> None:
    """Anchors off the floor between two on it (a side branch's mouth, or a floor too steep to ride): the bead
    crosses off the wall, held by the coil alone, on the route or on the chord between the two floor anchors,
    whichever needs less (the anchors are moved in place).  :class:`PlanInfeasible` names the stretch and the
    acceleration missing where the coil cannot hold it on either."""
    a_avail, a_sat, duty = available_accel(scenario)
    k = 1
    while k < len(pts):
        if follow[k] == 1.0 or follow[k - 1] != 1.0:
            k += 1
            continue
        end = k
        while end < len(pts) and follow[end] != 1.0:
            end += 1
        if end < len(pts):  # a crossing between two anchors on the floor
            chord = [(1.0 - lam) * anchors[k - 1] + lam * anchors[end]
                     for lam in ((j - (k - 1)) / (end - (k - 1)) for j in range(k, end))]
            # a chord on the floor (a glitch of one point) rests on it: within reach of the resting surface
            on_chord = max(_net_need(scenario, model, wall, c, tangents[j], v_cap, True)
                           for j, c in zip(range(k, end), chord))
            on_route = max(_net_need(scenario, model, wall, pts[j], tangents[j], v_cap, False) for j in range(k, end))
            if on_chord < on_route:  # on the chord, resting where it lies on the floor
                anchors[k:end] = chord
                follow[k:end] = 1.0
            worst = min(on_chord, on_route)
            if worst > a_avail:
                raise PlanInfeasible(
                    f"infeasible: the floor below the route breaks off at x {pts[k, 0] * 1e3:.1f}-"
                    f"{pts[end - 1, 0] * 1e3:.1f} mm (a side branch's mouth, or too steep to ride): crossing it off "
                    f"the wall needs {worst:.2f} m/s^2; the coil gives {a_avail:.2f} m/s^2 ({a_sat:.2f} at "
                    f"{duty:.0%} duty): {worst - a_avail:.2f} m/s^2 missing", missing_m_per_s2=worst - a_avail)
        k = end + 1


def _check_floor(scenario: Scenario, model: DynamicsModel, wall: MeshedWall, route: ReferenceTrajectory,
                 us: npt.NDArray[np.float64], anchors: npt.NDArray[np.float64], follow: npt.NDArray[np.float64],
                 tangents: npt.NDArray[np.float64], v_cap: float, options: PlanOptions) -> None:
    """Between two consecutive anchors on the floor, the floor below the route every 0.1 mm must stay within a
    bead radius of their chord; where it does not, the bead crosses off the wall, held by the coil alone.  Raises
    :class:`PlanInfeasible` naming the stretch and the acceleration missing when the coil cannot hold it there
    (the least need over the crossing's points, at the chord, the worst phase)."""
    a_avail, a_sat, duty = available_accel(scenario)
    r = scenario.physics.robot.radius_m
    for k in range(1, len(anchors)):
        if follow[k - 1] != 1.0 or follow[k] != 1.0:
            continue
        m = max(2, int(math.ceil((us[k] - us[k - 1]) / 1e-4)))
        broken, worst = [], 0.0
        for j in range(1, m):
            lam = j / m
            q = np.asarray(route.path_point(float(us[k - 1] + lam * (us[k] - us[k - 1]))))
            chord = (1.0 - lam) * anchors[k - 1] + lam * anchors[k]
            floor = wall.floor_below(q, options.wall_press_m)
            if floor is None or float(np.sqrt(((floor - chord) ** 2).sum())) > r:
                broken.append(float(q[0]))
                worst = max(worst, _net_need(scenario, model, wall, chord, tangents[k], v_cap, False))
        if broken and worst > a_avail:
            raise PlanInfeasible(
                f"infeasible: the floor below the route breaks off at x {min(broken) * 1e3:.1f}-"
                f"{max(broken) * 1e3:.1f} mm (a side branch's mouth or a junction): crossing it off the wall needs "
                f"{worst:.2f} m/s^2; the coil gives {a_avail:.2f} m/s^2 ({a_sat:.2f} at {duty:.0%} duty): "
                f"{worst - a_avail:.2f} m/s^2 missing", missing_m_per_s2=worst - a_avail)


def _fall_picks(fall: _Fall, touched: int, options: PlanOptions) -> list[int]:
    """The fall's samples that are anchors: every quarter spacing along it, and every sample around the landing
    (its kink would ring through a sparse spline)."""
    arc = _arc(fall.p)
    dense = int(round(0.004 / options.step_s))
    picks = [0]
    for k in range(1, len(arc) - 1):
        near = touched - dense <= k <= touched or (k > touched and (k - touched) % max(1, dense // 2) == 0)
        if near or (arc[k] - arc[picks[-1]] >= 0.25 * options.anchor_spacing_m and arc[-1] - arc[k] >= 0.1e-3):
            picks.append(k)
    picks.append(len(arc) - 1)
    return picks


def _fall_timing(fall: _Fall, picks: Sequence[int], anchor_u: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The path parameter along the fall at its samples: its arc length mapped onto the anchors' chords."""
    arc = _arc(fall.p)
    return np.interp(arc, arc[list(picks)], anchor_u[:len(picks)])


# ---------------------------------------------------------------------------------------------- timing
#: How often a pass waiting short of a crest looks again whether it can cross (s).
CREST_LOOK_EVERY_S = 0.005
#: A crest of the floor: along a bead diameter of the route, the floor's normal turns forward by this much of its
#: component along the route (about 30 deg): an up-slope that tops out and falls away.
CREST_TURN = 0.5


def _crests(traj: ReferenceTrajectory, wall: MeshedWall, radius_m: float,
            step_m: float = 5e-5) -> list[tuple[float, float]]:
    """The stretches of the path parameter ``(u_a, u_b)`` around each crest of the floor the route rests on: where,
    over a bead diameter, the still floor's normal turns forward along the route by more than :data:`CREST_TURN`
    (an up-slope that tops out and falls away, as a side branch's mouth seen from the floor of its parent).  A
    bead held there sits on a ridge: any slip forward puts it on the far slope, and the nearest wall (the plant's
    contact, the observer's and the law's model of it) flips between the two faces.  Each stretch reaches two
    bead radii either side of the turn; overlapping ones merge."""
    U = traj.length_m
    u = np.arange(0.0, U + 0.5 * step_m, step_m)
    if u.size < 3:
        return []
    pts = np.array([traj.path_point(float(v)) for v in u])
    tangent = np.gradient(pts, u, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), 1e-300)[:, None]
    _, normals, _ = wall.frames(0.0, pts, still=True)
    resting = traj.follow_weight(u)[0] >= 1.0 - 1e-9
    k = max(1, int(round(radius_m / step_m)))
    out: list[tuple[float, float]] = []
    for i in range(k, u.size - k):
        if not (resting[i - k] and resting[i + k]):
            continue
        turn = float(normals[i + k] @ tangent[i]) - float(normals[i - k] @ tangent[i])
        if turn > CREST_TURN:
            a, b = max(0.0, u[i] - 2.0 * radius_m), min(U, u[i] + 2.0 * radius_m)
            if out and a <= out[-1][1]:
                out[-1] = (out[-1][0], b)
            else:
                out.append((a, b))
    return out


def _floor_trajectory(ref: ReferenceParams, scenario: Scenario, wall: MeshedWall | None) -> ReferenceTrajectory:
    """``ref`` as the planner sees it: shifted as the plant's wall, and following the floor of ``wall`` as it
    pulsates (none in the straight vessel)."""
    motion = None if wall is None else WallMotion(wall.follow_offset, wall.pulsation, wall.omega, wall.phase)
    return ReferenceTrajectory(ref, wall_shift=wall_shift_of(scenario.physics), wall_motion=motion)


def crest_times(scenario: Scenario, reach_m: float = 1e-3) -> list[tuple[float, float]]:
    """The times at which a planned scenario's reference (``timing: planned``, as :func:`plan_scenario` writes it)
    runs within ``reach_m`` of a crest of the floor it rests on (:func:`_crests`), as ``(t_a, t_b)`` stretches (s);
    empty where the reference rests on no floor or crosses no crest."""
    ref = planned_reference(scenario)
    wall = meshed_wall(scenario)
    if wall is None or not ref.wall_follow or not ref.planned_t_s:
        return []
    traj = _floor_trajectory(ref, scenario, wall)
    t = float(ref.start_s) + np.asarray(ref.planned_t_s, dtype=np.float64)
    u = np.asarray(ref.planned_u_m, dtype=np.float64)
    out = []
    for a, b in _crests(traj, wall, scenario.physics.robot.radius_m):
        near = np.flatnonzero((u >= a - reach_m) & (u <= b + reach_m))
        if near.size:
            out.append((float(t[near[0]]), float(t[near[-1]])))
    return out


def _timing_pass(scenario: Scenario, traj: ReferenceTrajectory, model: DynamicsModel, t0: float, u0: float,
                 du0: float, budget: float, options: PlanOptions, v_cap: float,
                 a_avail: float = math.inf, no_stop: Sequence[tuple[float, float]] = ()
                 ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Greedy forward pass from ``(t0, u0, du0)``: times, path parameters and their speeds (module docstring: when).
    A pass that cannot move on is :class:`PlanInfeasible`, with the acceleration missing against the coil's
    ``a_avail`` where moving on needs more than that.

    ``no_stop``: stretches of the path parameter ``(u_a, u_b)`` the reference must not stop in (a crest of the
    floor, :func:`_crests`).  Before the pass would run into one it looks ahead (the same greedy steps, from the
    pace it would take): if that pass would stop before ``u_b``, it brakes and waits short of ``u_a`` instead,
    looking again every :data:`CREST_LOOK_EVERY_S`, until a pass crosses without stopping (or it cannot wait:
    the step that waits needs more than the budget)."""
    h, a_t, U = options.step_s, options.tangential_accel_m_per_s2, traj.length_m
    network = bool(scenario.physics.vessel.network)
    wall = meshed_wall(scenario)
    steps = np.linspace(-a_t, a_t, 9) * h
    t, u, du = t0, u0, du0
    ts, us, dus = [t], [u], [du]

    def needs_at(t: float, u: float, du: float,
                 speeds: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """The path parameters one step on at each of ``speeds`` from ``(t, u, du)``, and the need there."""
        un = np.minimum(u + 0.5 * (du + speeds) * h, U)
        tn = np.full(speeds.shape, t + h)
        p, v, a = traj.state(tn, un, speeds, (speeds - du) / h)
        return un, need(model, tn, p, v, a, rest_of(scenario, wall, tn), _resting(traj, un, wall))

    def step(t: float, u: float, du: float, budget: float = budget
             ) -> tuple[float, float, float, float, npt.NDArray[np.float64], npt.NDArray[np.float64],
                        npt.NDArray[np.float64], int]:
        """One greedy step from ``(t, u, du)`` within ``budget``: ``(t', u', du', least, candidates, their u',
        needs, the pick)``."""
        stop = math.sqrt(2.0 * a_t * max(U - u, 0.0))
        # the cap is on the axial speed: a change of height goes as fast as the need allows; along a network's
        # route, on the path speed (the route turns and climbs)
        slope = 1.0 if network else abs(float(traj.state(np.array([t]), np.array([u]), np.ones(1),
                                                         np.zeros(1))[1][0, 0]))
        cap = min(v_cap / max(slope, v_cap / options.max_path_speed_m_per_s), stop)
        cand = np.unique(np.clip(du + steps, 0.0, max(cap, du - a_t * h)))[::-1]
        un, need_c = needs_at(t, u, du, cand)
        ok = np.flatnonzero(need_c <= budget)
        if network and not ok.size:
            # no pace up to the cap holds the bead here (a systole against the bead in a network's trunk): ride
            # the flow, faster than the cap, at the slowest pace the budget allows, speeding up as fast as
            # half the budget (the flow's push does the rest)
            fast = np.unique(np.clip(du + steps * max(1.0, 0.5 * budget / a_t), 0.0,
                                     min(options.max_path_speed_m_per_s, stop)))
            fast = fast[fast > cap]
            if fast.size:
                un_f, need_f = needs_at(t, u, du, fast)
                ok_f = np.flatnonzero(need_f <= budget)
                i_f = int(ok_f[0]) if ok_f.size else int(np.argmin(need_f))
                if ok_f.size or need_f[i_f] < float(np.min(need_c)):
                    cand, un, need_c = fast[i_f:i_f + 1], un_f[i_f:i_f + 1], need_f[i_f:i_f + 1]
                    ok = np.flatnonzero(need_c <= budget)
        pick = int(ok[0]) if ok.size else int(np.argmin(need_c))
        moving = need_c[cand > 0.0]
        least = float(np.min(moving)) if moving.size else float(need_c[pick])
        return t + h, float(un[pick]), float(cand[pick]), least, cand, un, need_c, pick

    period = 2.0 * math.pi / scenario.physics.flow.angular_frequency_rad_per_s

    def crosses(t: float, u: float, du: float, u_b: float) -> bool:
        """Whether the greedy pass from ``(t, u, du)`` within ``crest_budget_share`` of the budget passes ``u_b``
        without stopping."""
        slow = 0.05 * v_cap
        low = options.crest_budget_share * budget
        for _ in range(int(period / h)):  # a crossing that takes longer than a cardiac period does not cross
            if u >= u_b or U - u <= 1e-9 * max(U, 1e-3):
                return True
            t, u, du, _least, _cand, _un, need_c, pick = step(t, u, du, low)
            if (du < slow or need_c[pick] > low) and u < u_b:
                return False
        return False

    zones = sorted((float(a), float(b)) for a, b in no_stop)
    look_every = max(1, int(round(CREST_LOOK_EVERY_S / h)))
    waited = 0  # steps waited short of a crest since the last look ahead
    since = math.inf  # when the pass began to wait short of the crest ahead
    least = math.inf  # the least need of a step that moves on, where the pass last was
    for _ in range(int(options.max_duration_s / h)):
        if U - u <= 1e-9 * max(U, 1e-3) or (du == 0.0 and U - u < 1e-7):
            break
        tn, un_p, du_p, least, cand, un, need_c, _pick = step(t, u, du)
        # a crest ahead: where this pace would stop (braking at the tangential limit) lies in it
        ahead = un_p + du_p * du_p / (2.0 * a_t)
        zone = next(((a, b) for a, b in zones if u < a <= ahead), None)
        if zone is not None and du_p > 0.0:
            if waited > 0 and waited < look_every and du == 0.0:
                go = False  # waiting: look again later
            else:
                go = crosses(tn, un_p, du_p, zone[1])
                waited = 0
            since = min(since, t)
            if not go and t - since > period:  # no phase of a whole period crosses it within the share: cross as
                zones.remove(zone)  # the budget allows (the check and the loop judge it)
                go = True
            if not go:
                low = int(np.argmin(cand))  # brake (or stay) short of the crest, if the budget holds the bead there
                if need_c[low] <= budget and un[low] + cand[low] ** 2 / (2.0 * a_t) < zone[0]:
                    tn, un_p, du_p = tn, float(un[low]), float(cand[low])
                    waited += 1
        if zone is None:
            since = math.inf
        t, u, du = tn, un_p, du_p
        ts.append(t)
        us.append(u)
        dus.append(du)
    else:
        where = traj.path_point(u)
        head = (f"the plan does not reach the end of the path within {options.max_duration_s:g} s (stuck at "
                f"{u * 1e3:.2f} of {U * 1e3:.2f} mm, x = {where[0] * 1e3:.2f} mm, z = {where[-1] * 1e3:.2f} mm): the "
                f"coil cannot move the bead on; moving on needs at least {least:.2f} m/s^2 there")
        if least > a_avail:
            raise PlanInfeasible(f"{head}; the coil gives {a_avail:.2f} m/s^2: {least - a_avail:.2f} m/s^2 missing",
                                 missing_m_per_s2=least - a_avail)
        raise PlanInfeasible(f"{head}, above the plan's budget of {budget:.2f} m/s^2")
    dus[-1] = 0.0
    return np.asarray(ts), np.asarray(us), np.asarray(dus)


def _smooth(dus: npt.NDArray[np.float64], options: PlanOptions) -> npt.NDArray[np.float64]:
    """The speeds smoothed by a centred Hann window of ``smooth_s`` (edges held); never negative."""
    w = max(3, int(round(options.smooth_s / options.step_s)) | 1)
    win = np.hanning(w + 2)[1:-1]
    win /= win.sum()
    pad = w // 2
    return convolve_valid(np.pad(dus, pad, mode="edge"), win)  # not np.convolve: its BLAS ddot sums by CPU kernel


def _table(ts: npt.NDArray[np.float64], us: npt.NDArray[np.float64], U: float, options: PlanOptions,
           keep: int = 0) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(planned_t_s, planned_u_m)`` from 0, ending at ``U``: the first ``keep`` samples, then every ``table_step_s``."""
    every = max(1, int(round(options.table_step_s / options.step_s)))
    idx = np.concatenate([np.arange(keep), np.arange(keep, ts.size, every)]).astype(int)
    if idx[-1] != ts.size - 1:
        idx = np.append(idx, ts.size - 1)
    t_tab, u_tab = ts[idx] - ts[0], np.maximum.accumulate(np.clip(us[idx], 0.0, U))
    u_tab[-1] = U
    return tuple(float(v) for v in t_tab), tuple(float(v) for v in u_tab)


# ---------------------------------------------------------------------------------------------- check
def evaluate(scenario: Scenario, options: PlanOptions | None = None) -> tuple[Segment, ...]:
    """Margins and coast floors of ``scenario``'s reference, segment by segment (module docstring: checked).

    A segment is ``anchor_spacing_m`` of the path (its parameter), the last
    one up to 1.5 times that; every sample of the reference between its start
    and its end time counts (every ``check_step_s``).
    """
    options = options or PlanOptions()
    traj = build_stages(scenario).reference
    if not isinstance(traj, ReferenceTrajectory):
        raise ConfigError(f"the planner checks the bspline reference kind only, got reference.kind "
                          f"{scenario.reference.kind!r}")
    model = DynamicsModel(scenario.physics, scenario.sim.integrator)
    a_avail, _, _ = available_accel(scenario)
    ts = np.arange(0.0, traj.end_time_s + 0.5 * options.check_step_s, options.check_step_s)
    p, v, a = traj.sample_many(ts)
    u = traj.parameter_at(ts)
    wall = meshed_wall(scenario)
    needs, on_wall = needs_on_wall(scenario, model, wall, ts, p, v, a, _resting(traj, u, wall))
    n_seg = max(1, int(math.floor(traj.length_m / options.anchor_spacing_m + 0.5)))
    bounds = np.append(options.anchor_spacing_m * np.arange(n_seg), traj.length_m)
    seg = np.clip(np.searchsorted(bounds, u, side="right") - 1, 0, n_seg - 1)
    t_c = coast_time_s(scenario)
    sels = [np.flatnonzero(seg == i) for i in range(n_seg)]
    # the coasts' plant time, before any is integrated: one line instead of a check that runs for hours
    plant_s = t_c * sum(_coast_starts(float(ts[sel[0]]), float(ts[sel[-1]]), t_c, options.coast_every_s).size
                        for sel in sels if sel.size)
    if plant_s > COAST_BUDGET_PLANT_S:
        seq = scenario.sequence
        raise ConfigError(
            f"sequence.tracking_window_s={seq.tracking_window_s!r}: checking this plan's coast floor would integrate "
            f"about {plant_s:.0f} s of plant time (coasts of {t_c:.4g} s without propulsion along "
            f"{traj.end_time_s:.3g} s of path), more than the planner's {COAST_BUDGET_PLANT_S:g} s: shorten the "
            f"tracking window or the dead time")
    out = []
    for i, sel in enumerate(sels):
        if sel.size == 0:
            continue
        k = sel[int(np.argmax(needs[sel]))]
        mode = "wall" if np.all(on_wall[sel]) else ("free" if not np.any(on_wall[sel]) else "mixed")
        try:
            floor = _coast_floor(scenario, traj, ts[sel[0]], ts[sel[-1]], t_c, options.coast_every_s, wall)
        except ModelInputError:  # a coast whose contact collapsed the step (a junction's edge): no floor is promised
            floor = math.inf
        out.append(Segment(i, float(traj.path_point(bounds[i])[0]), float(traj.path_point(bounds[i + 1])[0]), mode,
                           float(np.mean(p[sel, -1])), float(ts[sel[0]]), float(ts[sel[-1]]), float(needs[k]),
                           float(ts[k]), a_avail - float(needs[k]), floor))
    return tuple(out)


def reachable(scenario: Scenario, t: float, p: npt.NDArray[np.float64], v: npt.NDArray[np.float64],
              wall: MeshedWall | None = None) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """A reference point inside the lower wall (a network's or a tree's: ``wall``) moved onto it (where the bead
    is), with the wall's velocity."""
    if wall is not None:
        snapped = wall.snap(t, p, v)
        return snapped.p[0], snapped.v[0]
    rest = wall_rest(scenario, t)
    if rest is None or p[1] > rest[0][0]:
        return p, v
    return np.array([p[0], rest[0][0]]), np.array([v[0], rest[1][0]])


def _coast_starts(t_from: float, t_to: float, t_c: float, every_s: float) -> npt.NDArray[np.float64]:
    """When the coasts of one segment start (s): every ``every_s``, at most :data:`COAST_STARTS_PER_COAST` per coast."""
    return np.arange(t_from, t_to + 1e-12, max(every_s, t_c / COAST_STARTS_PER_COAST))


def _coast_floor(scenario: Scenario, traj: ReferenceTrajectory, t_from: float, t_to: float, t_c: float,
                 every_s: float, wall: MeshedWall | None = None) -> float:
    """Half the largest drift over one coast released on the (reachable) reference within ``[t_from, t_to]`` (m)."""
    if t_c <= 0.0:
        return 0.0
    plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
    d = plant.dims
    worst = 0.0
    for t0 in _coast_starts(t_from, t_to, t_c, every_s):
        s0 = traj.sample(float(t0))
        p0, v0 = reachable(scenario, float(t0), s0.p, s0.v, wall)
        y = np.concatenate([p0, v0]).astype(np.float64)
        plant.propagate(float(t0), float(t0) + t_c, y, np.zeros(d), plant.new_contact_state())
        s1 = traj.sample(float(t0) + t_c)
        p1, _ = reachable(scenario, float(t0) + t_c, s1.p, s1.v, wall)
        worst = max(worst, float(np.hypot(*(y[:d] - p1)) if d == 2 else np.linalg.norm(y[:d] - p1)))  # axis count: the plane keeps its bits
    return 0.5 * worst


# ---------------------------------------------------------------------------------------------- plan
def check_fits_path(scenario: Scenario) -> None:
    """Refuse a sequence whose coast (tracking window + 2 dead times) or latency is as long as the path's duration.

    The scenario loader already refuses a window or latency that does not fit
    in the run (``sim.duration_s``); the plan is checked against its path
    (``reference.duration_s``, the time the scenario's reference takes).

    Raises:
        ConfigError: one line naming the key, its value and the path's duration.
    """
    seq, ref = scenario.sequence, planned_reference(scenario)
    if seq.mode == "continuous":
        return
    path = f"the path's duration (reference.duration_s = {ref.duration_s!r} s)"
    if coast_time_s(scenario) >= ref.duration_s:
        raise ConfigError(f"sequence.tracking_window_s={seq.tracking_window_s!r}: a coast without propulsion "
                          f"(tracking window + 2 dead times = {coast_time_s(scenario):.6g} s) must be shorter than {path}")
    if seq.latency_s >= ref.duration_s:
        raise ConfigError(f"sequence.latency_s={seq.latency_s!r} must be shorter than {path}")


def make_plan(scenario: Scenario, options: PlanOptions | None = None) -> Plan:
    """Plan a reference the scanner can fly along ``scenario``'s path (module docstring).

    ``height``: ``free`` never rests on the lower wall; ``wall`` takes the
    least need at each anchor, the wall included; ``auto`` plans both and keeps
    the feasible one with the lower coast floor (then the shorter).  In a
    network or a tree ``auto`` keeps the route where it is feasible and rests on
    the floor below it only where it is not (a tree's floor has junctions and
    side branches' mouths; the route keeps to its branch).

    Raises:
        PlanInfeasible: no budget fraction gives a non-negative margin on every
            segment (the message names the worst segment and the acceleration
            missing), or the bead cannot be moved on to the end of the path.
        ConfigError: a sequence that does not fit the path (:func:`check_fits_path`), or a coast check
            over :data:`COAST_BUDGET_PLANT_S` of plant time (:func:`evaluate`).
    """
    options = options or PlanOptions()
    check_fits_path(scenario)
    heights = ("free", "wall") if options.height == "auto" else (options.height,)
    # one step per timing attempt (each evaluates the whole plan: about a second), at most retries + 1 a height
    with step(f"planning {scenario.name}") as report:
        total, done = len(heights) * (options.retries + 1), [0]

        def attempted() -> None:
            done[0] += 1
            report(done[0], total)

        report(0, total)
        if options.height != "auto":
            return _make_plan(scenario, options, attempted)
        plans: list[Plan] = []
        why: list[PlanInfeasible] = []
        network = bool(scenario.physics.vessel.network)
        for height in heights:
            if network and plans:
                break  # a network's route where the coil holds it; its floor only where it does not
            try:
                plans.append(_make_plan(scenario, dataclasses.replace(options, height=height), attempted))
            except PlanInfeasible as exc:
                why.append(exc)
            done[0] = heights.index(height) * (options.retries + 1) + options.retries + 1  # this height's share
            report(done[0], total)
        if not plans and network and len(why) == 2:  # the route, then its floor: both reasons, the lesser missing
            first, floor = why
            least = min(why, key=lambda e: e.missing_m_per_s2)
            raise PlanInfeasible(f"{first}; on the floor below the route: {floor}", segment=least.segment,
                                 missing_m_per_s2=least.missing_m_per_s2)
        if not plans:
            raise min(why, key=lambda e: e.missing_m_per_s2)
        return min(plans, key=lambda p: (round(p.coast_floor_m, 7), p.end_s))


def _make_plan(scenario: Scenario, options: PlanOptions, attempted: Callable[[], None] = lambda: None) -> Plan:
    model = DynamicsModel(scenario.physics, scenario.sim.integrator)
    a_avail, a_sat, duty = available_accel(scenario)
    ref0 = planned_reference(scenario)
    t0 = float(ref0.start_s)
    v_cap = options.max_speed_m_per_s or ReferenceTrajectory(ref0).length_m / ref0.duration_s
    g = _geometry(scenario, model, options, v_cap)
    network = bool(scenario.physics.vessel.network)
    # a network's plan keeps its outlet as the run's target, the anchors as given (the route's)
    geom = dataclasses.replace(ref0, **{f"anchors_{axis}_m": tuple(float(v) for v in g.anchors[:, j])
                                        for j, axis in enumerate(AXES[g.anchors.shape[1]])},
                               wall_follow=tuple(float(v) for v in g.follow) if np.any(g.follow) else (),
                               route_outlet=ref0.route_outlet if network else "",
                               route_anchors="given" if network else "planned",
                               timing="constant", planned_t_s=(), planned_u_m=())
    wall = meshed_wall(scenario) if np.any(g.follow) else None
    traj = _floor_trajectory(geom, scenario, wall)
    if g.fall is not None:  # the fall's own timing, then the pass from where it rests on the wall
        u_fall = _fall_timing(g.fall, g.fall_picks, traj.anchor_u_m)
        t_pre, u_pre = g.fall.t + t0, u_fall
        du_end = float(np.gradient(u_fall, g.fall.t)[-1])
    else:
        t_pre, u_pre, du_end = np.array([t0]), np.array([0.0]), 0.0
    crests = [] if wall is None else _crests(traj, wall, scenario.physics.robot.radius_m)
    fraction = options.budget_fraction
    worst: tuple[Segment, ...] = ()
    for _ in range(options.retries + 1):
        try:
            ts, us, dus = _timing_pass(scenario, traj, model, float(t_pre[-1]), float(u_pre[-1]), du_end,
                                       fraction * a_avail, options, v_cap, a_avail, crests)
        except PlanInfeasible:
            if not worst:
                raise
            break  # a smaller budget cannot move the bead on: the last check's worst segment is the reason
        sm = _smooth(dus, options)
        us = us[0] + np.concatenate([[0.0], np.cumsum(0.5 * (sm[1:] + sm[:-1]) * np.diff(ts))])
        if us[-1] > us[0]:
            us = us[0] + (us - us[0]) * (traj.length_m - us[0]) / (us[-1] - us[0])
        t_tab, u_tab = _table(np.concatenate([t_pre, ts[1:]]), np.concatenate([u_pre, us[1:]]), traj.length_m,
                              options, keep=t_pre.size)  # the fall at its own samples: its landing is sudden
        planned = dataclasses.replace(geom, timing="planned", duration_s=t_tab[-1], planned_t_s=t_tab,
                                      planned_u_m=u_tab)
        segs = evaluate(plan_scenario(scenario, planned), options)
        attempted()
        if min(s.margin_m_per_s2 for s in segs) >= 0.0:
            return Plan(planned, segs, a_avail, a_sat, duty, fraction, t0 + t_tab[-1],
                        tuple((float(a), float(b)) for a, b in crests))
        worst = segs
        fraction *= 0.85
    bad = min(worst, key=lambda s: s.margin_m_per_s2)
    raise PlanInfeasible(
        f"infeasible: {bad.describe(len(worst))} needs {bad.need_m_per_s2:.2f} m/s^2 at t = {bad.t_worst_s:.3f} s; "
        f"the coil gives {a_avail:.2f} m/s^2 ({a_sat:.2f} at {duty:.0%} duty): "
        f"{-bad.margin_m_per_s2:.2f} m/s^2 missing", segment=bad, missing_m_per_s2=-bad.margin_m_per_s2)


def plan_scenario(scenario: Scenario, reference: ReferenceParams) -> Scenario:
    """``scenario`` with ``reference`` as its reference, run until the reference ends."""
    mapping = scenario.to_mapping()
    mapping["reference"] = dataclasses.asdict(reference)
    mapping["sim"] = dict(mapping["sim"], duration_s=float(reference.start_s + reference.duration_s))
    return scenario_from_mapping(mapping)


#: The filter's restarts on a route that tops a crest of the floor (:func:`flying_changes`): a track an update flung
#: more than 5 frame sigmas from its frame, or that refused every frame for 0.1 s.  On the external carotid on 3 T
#: they turn two seeds of five that lost the bead at the crest (9 mm) into 0.4 and 1.0 mm (docs/reproduction.md).
CREST_RESTARTS: dict[str, float] = {"observer.ekf.flung_restart_sigmas": 5.0, "observer.ekf.max_rejection_s": 0.1}
#: The predictive controller's spread along the route where it tops a crest of the floor (controller.spread_m, as
#: the filter's rms error along the floor there, 18-28 um): it plans for the estimate 30 um ahead and behind, so it
#: no longer brakes a bead the frames put just past the top while it still climbs.  On the external carotid on 3 T
#: (0.125 mm floor anchors, the filter's wall constraint) it keeps the seed of five that the estimate alone lost at
#: the crest (4.0 mm to 0.14 mm; docs/reproduction.md, carotid_3t_flight).
CREST_SPREAD_M = 30e-6
#: The filter's prior on the blood-velocity scale for a plan on the wall: the paper's 5 % blood-velocity error
#: (the filter's default, 10 %, let the scale wander to 1.07-1.14 on the clinical plan, truth 0.95: 82 % of 100
#: seeds within 2x the coast floor against 92 % with this prior).
WALL_FLOW_SCALE_SIGMA0 = BLOOD_VELOCITY_ERROR


def flying_changes(scenario: Scenario, plan: Plan) -> dict[str, str | float]:
    """The loop's options a plan that rests on the lower wall needs (dotted keys; none for a plan that stays free).

    Law (24) and the predictive controller then leave the vertical to the weight and the wall
    (``controller.wall_contact: carried``), and the extended Kalman filter
    keeps its estimate out of the wall (``observer.ekf.wall_projection: lumen``) and starts
    from the blood-velocity scale's known uncertainty (``observer.ekf.flow_scale_sigma0``,
    :data:`WALL_FLOW_SCALE_SIGMA0`): on the wall the slow flow tells the filter little about
    the scale, so a wider prior lets frame noise carry it 10-20 % off.  Where the route tops a crest of the
    floor (``plan.crests``) the filter also restarts a track that an update flung away from its frame or that
    refused every frame for a tenth of a second (:data:`CREST_RESTARTS`, unless the scenario sets its own): over
    a crest a frame's noise can put the estimate on the far side while the bead is still on the near one; for
    the same reason the predictive controller plans for a spread of the estimate along the route there
    (``controller.spread_m``, :data:`CREST_SPREAD_M`, unless the scenario sets its own).
    """
    if all(s.mode == "free" for s in plan.segments):
        return {}
    out: dict[str, str | float] = {}
    if any(f.name == "wall_contact" for f in dataclasses.fields(scenario.controller)):  # the kinds that take the option
        out["controller.wall_contact"] = "carried"
    if plan.crests and getattr(scenario.controller, "spread_m", None) == 0.0:  # the predictive kind, unless set
        out["controller.spread_m"] = CREST_SPREAD_M
    if scenario.observer.kind == "ekf":
        out["observer.ekf.wall_projection"] = "lumen"
        out["observer.ekf.flow_scale_sigma0"] = WALL_FLOW_SCALE_SIGMA0
        if plan.crests:
            for key, value in CREST_RESTARTS.items():
                if getattr(scenario.observer.ekf, key.rpartition(".")[2]) == 0.0:  # 0: off, the filter's default
                    out[key] = value
    return out


def segments_table(segments: Sequence[Segment]) -> list[dict[str, Any]]:
    """The segments as rows (SI units)."""
    return [dataclasses.asdict(s) for s in segments]
