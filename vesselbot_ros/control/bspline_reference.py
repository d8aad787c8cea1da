"""C2 cubic B-spline reference trajectory through anchor points (Section III-A2).

The anchor points (frame W: x along the vessel, z vertical) are joined by an
interpolating cubic B-spline (``k=3``, natural end conditions; the spline
:func:`scipy.interpolate.make_interp_spline` builds, with its collocation system
solved without BLAS by :func:`vesselbot_ros.blas_free.interp_spline` so the
path is the same double for double on every CPU), so the path ``P(u)`` is C2 in
its chord-length parameter ``u`` (m).  The timing ``u(t)`` is a separate C2 map,
which is how the paper "rescales the reference velocity along this path":

* ``constant``: ``u = U t / T`` (constant parameter speed);
* ``rest_to_rest``: the quintic smoothstep ``u = U (10 s^3 - 15 s^4 + 6 s^5)``,
  ``s = t/T``, so the reference starts and ends at rest (C2 at both ends);
* ``flow_synchronised``: ``dx_ref/dt = c * v_f(t, P(u))`` where ``v_f`` is the
  axial blood velocity at the reference point and ``c = sync_ratio``: the
  reference drifts with the blood, which Section III-A2 recommends where
  ``F_m/F_tot < 1``.  ``sync_along: path`` reads it along the path for a route
  that turns (a network, a tree): ``du/dt = c (v_f . P'(u)) / |P'(u)|^2``, the
  blood's speed along the path's tangent (``x``, the default, is the printed form).  The ODE is integrated once on a 2 ms grid by the
  classical fourth-order Runge-Kutta method (scipy's RK45 computes its stages
  with BLAS ``gemv``, whose rounding depends on the CPU's kernel) and ``u(t)``
  is interpolated by FITPACK's not-a-knot cubic spline, so it is C2 too;
* ``planned``: ``u(t)`` given as a table (``planned_t_s``, ``planned_u_m``),
  interpolated the same way: what ``vesselbot plan``
  (:mod:`vesselbot_ros.analysis.plan`) writes, a timing the coil can fly.

``wall_follow`` (one weight in [0, 1] per anchor) lets the reference ride
the lower wall of the pulsating straight vessel: the point moves down by
``m(u) (D(t) - D) / 2`` where ``m`` blends the anchors' weights by the quintic
smoothstep between consecutive anchors (C2, never outside the two weights).
In a network or a tree the floor below the path moves by ``-eps(t) D n / 2``
(``D`` its local diameter, ``n`` its inward normal, :class:`WallMotion`), and the
point moves by ``m(u)`` times that: the same rule, on the meshed wall.
With weight 1 and the anchor at ``z = -(D/2 - r - gap)`` the reference rests
on the wall at every phase, where the wall carries the bead's weight.

``X_ref = P(u)``, ``Xd_ref = P'(u) u'``, ``Xdd_ref = P''(u) u'^2 + P'(u) u''``.
Outside ``[t_start, t_start + T]`` the reference holds its end point with zero
velocity and acceleration.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from vesselbot_ros.blas_free import interp_spline, interp_spline_fitpack
from vesselbot_ros.config import OMIT_IF, ConfigError, check_choice, check_finite, check_nonnegative, check_positive
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.resources import require_fits, spline_setup_cost

if TYPE_CHECKING:  # the splines come from blas_free, which imports scipy.interpolate when it builds one
    from scipy.interpolate import BSpline

__all__ = [
    "ReferenceParams",
    "RefSample",
    "ReferenceTrajectory",
    "CompiledReference",
    "propose_anchors",
    "lower_wall_shift",
    "sinusoid",
    "WallMotion",
    "wall_shift_of",
]

#: ``(t, point (d,)) -> blood velocity (d,)`` (m/s) at the point.
FlowVelocityFn = Callable[[float, npt.NDArray[np.float64]], npt.NDArray[np.float64]]
class WallMotion(NamedTuple):
    """How the wall nearest a path moves with the eq. (13) pulsation ``eps(t) = A sin(w t + phi)``: by
    ``-eps(t) offset(p)`` at the path's point ``p``, ``offset`` giving ``D n / 2`` of that wall at each of
    (n, d) points (a network's or a tree's meshed wall, :func:`~vesselbot_ros.physics.integrator.wall_offsets`)."""

    offset: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]
    pulsation: float
    omega_rad_per_s: float
    phase_rad: float


#: ``t (n,) -> (h, dh/dt, d2h/dt2)``: how far the straight vessel's lower wall moved down, ``(D(t) - D) / 2`` (m).
WallShiftFn = Callable[[npt.NDArray[np.float64]], tuple[npt.NDArray[np.float64], ...]]


def sinusoid(amp: float, omega_rad_per_s: float, phase_rad: float) -> WallShiftFn:
    """``t -> (amp sin(w t + phi), its first and second time derivatives)``."""

    def shift(t: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], ...]:
        arg = omega_rad_per_s * t + phase_rad
        s, c = np.sin(arg), np.cos(arg)
        return amp * s, amp * omega_rad_per_s * c, -amp * omega_rad_per_s**2 * s

    return shift


def lower_wall_shift(diameter_m: float, pulsation: float, omega_rad_per_s: float, phase_rad: float) -> WallShiftFn:
    """The lower wall's displacement of eq. (13)'s pulsating vessel, ``D(t) = D (1 + A sin(w t + phi))``."""
    return sinusoid(0.5 * diameter_m * pulsation, omega_rad_per_s, phase_rad)


def wall_shift_of(physics: Any) -> WallShiftFn | None:
    """:func:`lower_wall_shift` of a ``PhysicsParams``'s straight vessel; ``None`` in a network (no one lower wall)."""
    if physics.vessel.network:
        return None
    f = physics.flow
    return lower_wall_shift(physics.vessel.diameter_m, f.diameter_pulsation, f.angular_frequency_rad_per_s, f.phase_rad)


@dataclasses.dataclass(frozen=True)
class ReferenceParams:
    """Anchor points and timing of the reference trajectory.

    Attributes:
        anchors_x_m: x of the anchor points along the vessel (m), >= 2 points.
        anchors_z_m: z of the anchor points (m), same length (0 = centreline).
        anchors_y_m: y of the anchor points (m), same length, for a path in
            three dimensions (a 3-D vessel tree); ``()`` (the default): the
            paper's XZ plane, and the trajectory's vectors have two components
            (x, z); with it, three (x, y, z).  Left out of
            :func:`~vesselbot_ros.config.to_mapping` (and of every hash) when empty.
        duration_s: Time ``T`` to run along the whole path (s).
        start_s: Time at which the reference leaves the first anchor (s).
        timing: ``constant``, ``rest_to_rest``, ``flow_synchronised`` or ``planned``.
        sync_ratio: ``c`` in ``dx_ref/dt = c v_f`` (flow_synchronised only).
        sync_along: ``x``: the printed ``dx_ref/dt = c v_fx`` (the path must be monotonic
            in x); ``path``: the blood's speed along the path's tangent drives the path
            parameter, ``du/dt = c (v_f . P') / |P'|^2`` (any route).
        planned_t_s: ``planned`` timing: times from ``start_s`` (s), from 0 to ``duration_s``, increasing.
        planned_u_m: ``planned`` timing: the path parameter at those times (m), from 0 to the path's length.
        wall_follow: Per anchor, the share of the lower wall's pulsation the
            reference follows, in [0, 1] (straight vessel only); ``()``: none.
        route_outlet: In a vessel network (``physics.vessel.network``): the
            target outlet branch; the anchors are then planned along the route
            from the start point (:mod:`vesselbot_ros.control.route`) and
            ``anchors_x_m``/``anchors_z_m`` are not used (unless ``route_anchors``
            is ``given``).  ``""``: the anchors as given.
        route_anchors: With ``route_outlet``: ``planned`` (the default) plans the
            anchors along the route; ``given`` keeps the anchors as given (a
            plan's, ``vesselbot plan``) and the outlet is the run's target only.
            Left out of :func:`~vesselbot_ros.config.to_mapping` (and of every hash) when ``planned``.
        route_anchor_spacing_m: Arc length between planned anchors (m).
        route_end_margin_m: The planned anchors end this far before the outlet (m).
        route_end: Where the last planned anchor lies.  ``spaced`` (the default):
            anchors every ``route_anchor_spacing_m`` from the start, the last
            between ``route_end_margin_m`` and that plus one spacing before the
            outlet (in a short outlet branch it can lie short of the branch's
            entrance).  ``at_margin``: the fewest anchors evenly spaced at most
            ``route_anchor_spacing_m`` apart, the last exactly
            ``route_end_margin_m`` before the outlet.  Left out of
            :func:`~vesselbot_ros.config.to_mapping` (and of every hash) when ``spaced``.
        route_wall_margin_m: Margin of the planned height outside the observer's unstable band (m).
        kind: The reference's stage kind (:mod:`vesselbot_ros.sim.kinds`): ``bspline``.
    """

    anchors_x_m: tuple[float, ...] = (0.0, 3e-3, 6e-3, 9e-3)
    anchors_z_m: tuple[float, ...] = (1e-3, 0.9e-3, 1e-3, 0.9e-3)
    duration_s: float = 2.0
    start_s: float = 0.0
    timing: Literal["constant", "rest_to_rest", "flow_synchronised", "planned"] = "constant"
    sync_ratio: float = 1.0
    planned_t_s: tuple[float, ...] = ()
    planned_u_m: tuple[float, ...] = ()
    wall_follow: tuple[float, ...] = ()
    route_outlet: str = ""
    kind: Literal["bspline"] = "bspline"
    route_anchor_spacing_m: float = 2.5e-3
    route_end_margin_m: float = 2.0e-3
    route_wall_margin_m: float = 1.5e-4
    anchors_y_m: tuple[float, ...] = dataclasses.field(default=(), metadata={OMIT_IF: lambda v: not v})
    route_end: Literal["spaced", "at_margin"] = dataclasses.field(default="spaced",
                                                                  metadata={OMIT_IF: lambda v: v == "spaced"})
    sync_along: Literal["x", "path"] = dataclasses.field(default="x", metadata={OMIT_IF: lambda v: v == "x"})
    route_anchors: Literal["planned", "given"] = dataclasses.field(default="planned",
                                                                   metadata={OMIT_IF: lambda v: v == "planned"})

    def __post_init__(self) -> None:
        if len(self.anchors_x_m) < 2:
            raise ConfigError(f"anchors_x_m needs at least 2 points, got {list(self.anchors_x_m)}")
        if len(self.anchors_z_m) != len(self.anchors_x_m):
            raise ConfigError(
                f"anchors_z_m must have as many points as anchors_x_m ({len(self.anchors_x_m)}), "
                f"got {len(self.anchors_z_m)}"
            )
        n = len(self.anchors_x_m)  # the spline's dense collocation solve grows as n^2 (memory) and n^2 (time)
        require_fits("anchors_x_m", f"{n} points", *spline_setup_cost(n), what="the reference's B-spline set-up",
                     hint="use fewer anchors")
        for i, v in enumerate(self.anchors_x_m):
            check_finite(f"anchors_x_m[{i}]", v)
        for i, v in enumerate(self.anchors_z_m):
            check_finite(f"anchors_z_m[{i}]", v)
        if self.anchors_y_m and len(self.anchors_y_m) != len(self.anchors_x_m):
            raise ConfigError(f"anchors_y_m must be empty or have as many points as anchors_x_m "
                              f"({len(self.anchors_x_m)}), got {len(self.anchors_y_m)}")
        for i, v in enumerate(self.anchors_y_m):
            check_finite(f"anchors_y_m[{i}]", v)
        pts = self.anchor_points()
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        if np.any(seg <= 0.0):
            i = int(np.argmin(seg))
            raise ConfigError(f"anchors must be distinct, got a repeated point at index {i + 1}: {pts[i + 1].tolist()}")
        check_positive("duration_s", self.duration_s)
        check_nonnegative("start_s", self.start_s)
        check_choice("timing", self.timing, ("constant", "rest_to_rest", "flow_synchronised", "planned"))
        self._check_planned()
        if self.wall_follow and len(self.wall_follow) != len(self.anchors_x_m):
            raise ConfigError(f"wall_follow must have one weight per anchor ({len(self.anchors_x_m)}), "
                              f"got {len(self.wall_follow)}")
        for i, w in enumerate(self.wall_follow):
            if not (math.isfinite(w) and 0.0 <= w <= 1.0):
                raise ConfigError(f"wall_follow[{i}] must be in [0, 1], got {w!r}")
        check_choice("kind", self.kind, ("bspline",))
        check_positive("sync_ratio", self.sync_ratio)
        check_positive("route_anchor_spacing_m", self.route_anchor_spacing_m)
        check_nonnegative("route_end_margin_m", self.route_end_margin_m)
        check_nonnegative("route_wall_margin_m", self.route_wall_margin_m)
        check_choice("route_end", self.route_end, ("spaced", "at_margin"))
        check_choice("sync_along", self.sync_along, ("x", "path"))
        check_choice("route_anchors", self.route_anchors, ("planned", "given"))

    def anchor_points(self) -> npt.NDArray[np.float64]:
        """(n, 2) anchors (x, z) in the plane, or (n, 3) (x, y, z) with ``anchors_y_m`` (m)."""
        cols = [self.anchors_x_m, self.anchors_y_m, self.anchors_z_m] if self.anchors_y_m else [self.anchors_x_m,
                                                                                               self.anchors_z_m]
        return np.column_stack(cols).astype(np.float64)

    def _check_planned(self) -> None:
        t, u = self.planned_t_s, self.planned_u_m
        if self.timing != "planned":
            if t or u:
                raise ConfigError(f"planned_t_s / planned_u_m apply to timing 'planned' only, got timing {self.timing!r}")
            return
        if len(t) < 4 or len(u) != len(t):
            raise ConfigError(f"timing 'planned' needs planned_t_s and planned_u_m of one length >= 4, got {len(t)} "
                              f"and {len(u)}")
        for name, vals in (("planned_t_s", t), ("planned_u_m", u)):
            for i, v in enumerate(vals):
                check_finite(f"{name}[{i}]", v)
        if t[0] != 0.0 or u[0] != 0.0:
            raise ConfigError(f"planned_t_s and planned_u_m must start at 0, got {float(t[0])!r} and {float(u[0])!r}")
        dt, du = np.diff(t), np.diff(u)
        if np.any(dt <= 0.0):
            i = int(np.argmin(dt)) + 1
            raise ConfigError(f"planned_t_s must increase, got {float(t[i])!r} after {float(t[i - 1])!r} at index {i}")
        if np.any(du < 0.0):
            i = int(np.argmin(du)) + 1
            raise ConfigError(f"planned_u_m must not decrease, got {float(u[i])!r} after {float(u[i - 1])!r} "
                              f"at index {i}")
        if abs(t[-1] - self.duration_s) > 1e-9 * max(1.0, self.duration_s):
            raise ConfigError(f"timing 'planned': duration_s must equal planned_t_s[-1] ({t[-1]!r}), "
                              f"got {self.duration_s!r}")


class RefSample(NamedTuple):
    """Reference at one time: ``X_ref``, ``Xd_ref``, ``Xdd_ref`` of eq. (24).

    Attributes:
        p: (2,) position (x, z), m, frame W; (3,) (x, y, z) for a 3-D path.
        v: (2,) velocity, m/s.
        a: (2,) acceleration, m/s^2.
    """

    p: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]
    a: npt.NDArray[np.float64]


@dataclasses.dataclass(frozen=True)
class CompiledReference:
    """A reference in the compiled loop's form: sampled once at every tick time, the loop reading tick k's row.

    Attributes:
        sample_many: ``sample_many(t_s) -> (p, v, a)``, each (n, d), at the (n,) tick times (the stage's own).
    """

    sample_many: Callable[[npt.NDArray[np.float64]], tuple[npt.NDArray[np.float64], ...]]

    def at_ticks(self, t_s: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], ...]:
        """``(p, v, a)`` at the tick times ``t_s``, C-contiguous."""
        return tuple(np.ascontiguousarray(a, dtype=np.float64) for a in self.sample_many(t_s))


class ReferenceTrajectory:
    """C2 reference trajectory ``t -> (X_ref, Xd_ref, Xdd_ref)``.

    Args:
        params: Anchors and timing.
        flow_velocity: ``v_f(t_s, p_W) -> (d,) m/s``, the blood velocity at a
            point; required for ``timing == "flow_synchronised"``.
        wall_shift: The straight vessel's lower wall displacement (:func:`lower_wall_shift`);
            it or ``wall_motion`` is required when a ``wall_follow`` weight is not 0.
        wall_motion: How the meshed wall of a network or a tree moves (:class:`WallMotion`), used
            when ``wall_shift`` is not given.

    Raises:
        ConfigError: if ``flow_synchronised`` is asked without a flow function, a
            wall to follow without its displacement, or a ``planned`` timing that
            does not end at the path's end.
    """

    def __init__(self, params: ReferenceParams, flow_velocity: FlowVelocityFn | None = None,
                 wall_shift: WallShiftFn | None = None, wall_motion: WallMotion | None = None) -> None:
        self.params = params
        pts = params.anchor_points()
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        self.anchor_u_m = np.concatenate([[0.0], np.cumsum(seg)])
        self.length_m = float(self.anchor_u_m[-1])
        k = 3 if len(pts) >= 4 else len(pts) - 1
        self._path: BSpline = interp_spline(self.anchor_u_m, pts, k=k)
        self._d1 = self._path.derivative(1)
        self._d2 = self._path.derivative(2) if k >= 2 else None
        self._t0 = float(params.start_s)
        self._T = float(params.duration_s)
        self._timing_spline: BSpline | None = None
        if params.timing == "flow_synchronised":
            if flow_velocity is None:
                raise ConfigError("reference.timing 'flow_synchronised' needs the blood-flow velocity function")
            self._timing_spline = self._synchronised_timing(flow_velocity)
        elif params.timing == "planned":
            u_end = params.planned_u_m[-1]
            if abs(u_end - self.length_m) > 1e-9 * max(self.length_m, 1e-3):
                raise ConfigError(f"reference.planned_u_m must end at the path's length {self.length_m!r} m, "
                                  f"got {float(u_end)!r}")
            self._timing_spline = interp_spline_fitpack(np.asarray(params.planned_t_s, dtype=np.float64),
                                                        np.asarray(params.planned_u_m, dtype=np.float64))
        self._follow = np.asarray(params.wall_follow, dtype=np.float64) if any(params.wall_follow) else None
        if self._follow is not None and wall_shift is None and wall_motion is None:
            raise ConfigError("reference.wall_follow needs the wall's motion: a straight vessel's lower wall "
                              "(wall_shift) or a network's meshed wall (wall_motion)")
        self._wall_shift = wall_shift
        self._motion = wall_motion if self._follow is not None and wall_shift is None else None
        self._offset: list[BSpline] = []
        if self._motion is not None:
            # D n / 2 of the wall nearest the path, every 0.1 mm of it, as C2 splines in u (FITPACK: no BLAS)
            n = int(min(4000, max(16, math.ceil(self.length_m / 1e-4) + 1)))
            us = np.linspace(0.0, self.length_m, n)
            w = np.asarray(self._motion.offset(np.ascontiguousarray(self._path(us))), dtype=np.float64)
            self._offset = [interp_spline_fitpack(us, np.ascontiguousarray(w[:, j])) for j in range(w.shape[1])]

    def _synchronised_timing(self, vf: FlowVelocityFn) -> BSpline:
        c = self.params.sync_ratio
        U = self.length_m

        along_path = self.params.sync_along == "path"

        def rhs(t: float, u: float) -> float:
            u = min(max(u, 0.0), U)
            p = self._path(u)
            d1 = [float(v) for v in self._d1(u)]
            flow = vf(self._t0 + t, p)
            if along_path:  # Python floats, not a BLAS dot: the same doubles on every CPU
                du = c * sum(float(f) * g for f, g in zip(flow, d1)) / sum(g * g for g in d1)
            else:
                if abs(d1[0]) < 1e-9:
                    raise ConfigError("flow_synchronised timing needs a path monotonic in x (dx/du = 0 found; "
                                      "reference.sync_along 'path' follows any route)")
                du = c * float(flow[0]) / d1[0]
            if (u <= 0.0 and du < 0.0) or (u >= U and du > 0.0):
                du = 0.0
            if not math.isfinite(du):
                raise ModelInputError(f"flow-synchronised timing: non-finite parameter speed at t={t!r}")
            return du

        n = max(201, int(self._T * 500) + 1)
        ts = np.linspace(0.0, self._T, n)
        u = np.empty(n)
        u[0] = 0.0
        for i in range(n - 1):  # classical RK4, Python floats: the same doubles on every CPU
            t, h, y = float(ts[i]), float(ts[i + 1] - ts[i]), float(u[i])
            k1 = rhs(t, y)
            k2 = rhs(t + 0.5 * h, y + 0.5 * h * k1)
            k3 = rhs(t + 0.5 * h, y + 0.5 * h * k2)
            k4 = rhs(t + h, y + h * k3)
            u[i + 1] = y + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return interp_spline_fitpack(ts, np.clip(u, 0.0, U))

    def _timing(self, t: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], ...]:
        """Return ``(u, du/dt, d2u/dt2)`` for times ``t`` (any shape)."""
        U, T = self.length_m, self._T
        tau = t - self._t0
        inside = (tau >= 0.0) & (tau <= T)
        tc = np.clip(tau, 0.0, T)
        timing = self.params.timing
        if timing == "constant":
            u = U * tc / T
            du = np.full_like(tc, U / T)
            ddu = np.zeros_like(tc)
        elif timing == "rest_to_rest":
            s = tc / T
            u = U * s**3 * (10.0 - 15.0 * s + 6.0 * s**2)
            du = U / T * 30.0 * s**2 * (1.0 - s) ** 2
            ddu = U / T**2 * 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s)
        else:
            assert self._timing_spline is not None
            u = self._timing_spline(tc)
            if timing == "planned":  # the table's spline may overshoot its ends by rounding
                u = np.clip(u, 0.0, U)
            du = self._timing_spline(tc, 1)
            ddu = self._timing_spline(tc, 2)
        du = np.where(inside, du, 0.0)
        ddu = np.where(inside, ddu, 0.0)
        return u, du, ddu

    def compiled(self) -> CompiledReference:
        """This reference in the compiled loop's form (its samples at the tick times)."""
        return CompiledReference(self.sample_many)

    def sample_many(self, t_s: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], ...]:
        """Vectorised :meth:`sample`.

        Args:
            t_s: (n,) times (s).

        Returns:
            ``(p, v, a)``, each (n, 2) (or (n, 3) for a 3-D path): position (m), velocity (m/s) and
            acceleration (m/s^2) in frame W.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if not np.all(np.isfinite(t)):
            raise ModelInputError("reference times must be finite")
        u, du, ddu = self._timing(t)
        return self.state(t, u, du, ddu)

    def state(self, t: npt.NDArray[np.float64], u: npt.NDArray[np.float64], du: npt.NDArray[np.float64],
              ddu: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], ...]:
        """``(p, v, a)`` (n, 2) (3-D path: (n, 3)) at times ``t`` for path parameter ``u`` and its derivatives (what a timing gives)."""
        p = self._path(u)
        d1 = self._d1(u)
        d2 = self._d2(u) if self._d2 is not None else np.zeros_like(d1)
        v = d1 * du[:, None]
        a = d2 * (du**2)[:, None] + d1 * ddu[:, None]
        if self._motion is not None:
            self._follow_wall(t, u, du, ddu, p, v, a)
        elif self._follow is not None:
            assert self._wall_shift is not None
            m, m_u, m_uu = self.follow_weight(u)
            h, hd, hdd = self._wall_shift(t)
            p[:, -1] -= m * h  # z, the last component in the plane and in 3-D
            v[:, -1] -= m_u * du * h + m * hd
            a[:, -1] -= (m_uu * du**2 + m_u * ddu) * h + 2.0 * m_u * du * hd + m * hdd
        return p, v, a

    def _follow_wall(self, t: npt.NDArray[np.float64], u: npt.NDArray[np.float64], du: npt.NDArray[np.float64],
                     ddu: npt.NDArray[np.float64], p: npt.NDArray[np.float64], v: npt.NDArray[np.float64],
                     a: npt.NDArray[np.float64]) -> None:
        """Move ``(p, v, a)`` in place by ``-eps(t) m(u) W(u)`` (``W = D n / 2`` of the nearest meshed wall) and its
        time derivatives."""
        assert self._motion is not None
        m, m_u, m_uu = self.follow_weight(u)
        w = np.column_stack([s(u) for s in self._offset])
        w_u = np.column_stack([s(u, 1) for s in self._offset])
        w_uu = np.column_stack([s(u, 2) for s in self._offset])
        g = m[:, None] * w
        g_u = m_u[:, None] * w + m[:, None] * w_u
        g_uu = m_uu[:, None] * w + 2.0 * m_u[:, None] * w_u + m[:, None] * w_uu
        e, e1, e2 = (x[:, None] for x in sinusoid(self._motion.pulsation, self._motion.omega_rad_per_s,
                                                  self._motion.phase_rad)(t))  # eps(t) of eq. (13)
        du_, ddu_ = du[:, None], ddu[:, None]
        p -= e * g
        v -= e1 * g + e * g_u * du_
        a -= e2 * g + 2.0 * e1 * g_u * du_ + e * (g_uu * du_**2 + g_u * ddu_)

    def follow_weight(self, u: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], ...]:
        """``(m, dm/du, d2m/du2)`` of the wall-follow weight at path parameter ``u`` (zeros without ``wall_follow``)."""
        u = np.asarray(u, dtype=np.float64)
        if self._follow is None:
            z = np.zeros_like(u)
            return z, z.copy(), z.copy()
        knots, w = self.anchor_u_m, self._follow
        i = np.clip(np.searchsorted(knots, u, side="right") - 1, 0, len(knots) - 2)
        span = knots[i + 1] - knots[i]
        s = np.clip((u - knots[i]) / span, 0.0, 1.0)
        dw = w[i + 1] - w[i]
        m = w[i] + dw * s**3 * (10.0 - 15.0 * s + 6.0 * s**2)
        m_u = dw * 30.0 * s**2 * (1.0 - s) ** 2 / span
        m_uu = dw * 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s) / span**2
        return m, m_u, m_uu

    def sample(self, t_s: float) -> RefSample:
        """Reference at time ``t_s`` (s): position, velocity, acceleration.

        Raises:
            ModelInputError: if ``t_s`` is not finite.
        """
        if not math.isfinite(t_s):
            raise ModelInputError(f"reference time must be finite, got {t_s!r}")
        p, v, a = self.sample_many(np.array([t_s]))
        return RefSample(p[0], v[0], a[0])

    def parameter_at(self, t_s: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The path parameter ``u`` (m) at times ``t_s`` (s)."""
        return np.asarray(self._timing(np.atleast_1d(np.asarray(t_s, dtype=np.float64)))[0])

    def path_point(self, u_m: float) -> npt.NDArray[np.float64]:
        """The path's point at parameter ``u_m`` (m), without the wall's pulsation."""
        return np.asarray(self._path(float(u_m)))

    def path(self, n: int = 200) -> npt.NDArray[np.float64]:
        """(n, 2) (3-D path: (n, 3)) points evenly spaced in the path parameter, m (for a Path message)."""
        if n < 2:
            raise ModelInputError(f"path needs n >= 2 points, got {n}")
        return np.asarray(self._path(np.linspace(0.0, self.length_m, n)))

    @property
    def end_time_s(self) -> float:
        """Time at which the reference reaches its last anchor (s)."""
        return self._t0 + self._T


def propose_anchors(
    x_start_m: float,
    x_end_m: float,
    n_anchors: int,
    delta_grid_m: npt.ArrayLike,
    ratio_of_delta: Callable[[float], float],
) -> ReferenceParams:
    """Propose anchors from a design-map cut ``F_m/F_tot`` versus ``Delta``.

    Section III-A2: put the path where ``F_m/F_tot`` is largest: near the
    upper wall in arteries (interaction forces balance the apparent weight
    and the parabolic flow is slow there), centred in small vessels.  The
    physics decides which: this helper takes the ratio as a callable (e.g. a
    cut of the Fig. 7 map at the chosen ``lambda``) and returns anchors at
    evenly spaced ``x`` and the best ``Delta``.

    Args:
        x_start_m: x of the first anchor (m).
        x_end_m: x of the last anchor (m), > ``x_start_m``.
        n_anchors: Number of anchors, >= 2 (the paper uses four).
        delta_grid_m: Candidate signed distances ``Delta`` to the centreline (m);
            restrict it to where the robot fits (``|Delta| <= D/2 - r - margin``).
        ratio_of_delta: ``Delta -> F_m/F_tot`` (dimensionless).

    Returns:
        :class:`ReferenceParams` with the proposed anchors (``constant`` timing).
        If the best ratio is below 1 the caller should switch to
        ``flow_synchronised`` timing (Section III-A2).

    Raises:
        ConfigError: on an empty grid, ``n_anchors < 2`` or ``x_end <= x_start``.
    """
    grid = np.asarray(delta_grid_m, dtype=np.float64).ravel()
    if grid.size == 0 or not np.all(np.isfinite(grid)):
        raise ConfigError("delta_grid_m must be a non-empty array of finite distances")
    if n_anchors < 2:
        raise ConfigError(f"n_anchors must be >= 2, got {n_anchors}")
    if not x_end_m > x_start_m:
        raise ConfigError(f"x_end_m must be > x_start_m, got {x_end_m!r} <= {x_start_m!r}")
    ratios = np.array([ratio_of_delta(float(d)) for d in grid])
    if not np.all(np.isfinite(ratios)):
        raise ModelInputError("ratio_of_delta returned a non-finite value")
    best = float(np.max(ratios))
    # ties: prefer the point closest to the centreline
    candidates = grid[np.isclose(ratios, best, rtol=1e-9, atol=0.0)]
    delta = float(candidates[np.argmin(np.abs(candidates))])
    xs = tuple(float(x) for x in np.linspace(x_start_m, x_end_m, n_anchors))
    return ReferenceParams(anchors_x_m=xs, anchors_z_m=(delta,) * n_anchors)
