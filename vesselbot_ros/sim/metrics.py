"""Closed-loop metrics computed from a time-series dict (runner or recorded bag).

:func:`compute_metrics` needs only these keys (each a 1-D array over ticks, or
(n, 2) for vectors):

==================  ======  ===================================================
key                 unit    meaning
==================  ======  ===================================================
``t_s``             s       tick time
``p_true``          m       (n, 2) true position, frame W
``v_true``          m/s     (n, 2) true velocity
``p_ref``           m       (n, 2) reference position
``x_hat``           m       (n, 2) estimated position
``z_hat``           m/s     (n, 2) estimated velocity
``g_applied``       T/m     (n, 2) gradient applied by the coil from ``t_s`` on
``saturated``       bool    saturation active (``k > 1``) at the tick
``slew_limited``    bool    (n, 2) slew limit active per axis
``in_contact``      bool    robot touches a wall (``delta > 0``) at the tick
==================  ======  ===================================================

Returned keys (all floats / ints, SI units in the name):

* ``tracking_error_max_m``, ``tracking_error_rms_m``: ``||p_true - p_ref||``
  over ``t >= after_s`` (paper: 150 um bound after 0.6 s);
* ``tracking_error_max_all_m``: same over the whole run;
* ``estimation_error_max_m``, ``estimation_error_rms_m``: ``||x_hat - p_true||``
  over ``t >= after_s`` (paper: < 10 um after the transient);
* ``velocity_estimation_error_max_m_per_s``, ``velocity_estimation_error_rms_m_per_s``;
* ``saturation_time_s``, ``slew_limited_time_s``: time with saturation / any
  axis slew-limited (ticks times the tick period), whole run;
* ``wall_contacts``: number of contact onsets; ``contact_time_s``;
* ``max_gradient_T_per_m``: largest ``||g_applied||``;
* ``rejected_commands``: ticks whose command the coil rejected (non-finite,
  not a command, ...: it ramped towards zero at the slew limit), when the
  series has the optional ``cmd_rejected`` column (non-zero = rejected: the
  loops' rejection codes, or a bag's ``coil.rejected``); and, only when it is
  not 0, ``first_rejected_command_s``: the time of the first such tick (s);
* ``after_s``, ``duration_s``, ``n_ticks``: ``after_s`` is the start of the
  window actually used; a run that ends before the requested window starts
  is reported over the whole run (``after_s`` = first tick) and
  ``metrics_window_note`` says so in words;
* ``diverged_at_s``: the first tick at which the run diverged (below), or
  None; ``divergence``: what diverged, in words (None when it did not);
* ``status``: the run's outcome, :func:`run_status`: ``ok``, ``diverged``
  or ``rejected_commands``.  Every command reads it (``vesselbot simulate``
  and ``run`` warn in one line and exit 1 when it is not ``ok``; a campaign's
  and the scanner study's tables carry it).

Divergence (the one rule, :func:`diverged_at`): at some tick the true
position or the estimate lies farther from the reference than
:func:`divergence_bound_m` (``max(10 vessel diameters, 10 mm)``: a bead or
an estimate that far is outside any vessel the run models), or is not finite
(NaN only where every tick is computed, ``nonfinite_diverges``: in a real-time
run NaN marks a sample that never arrived).  The whole run counts, not just
the metrics window.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ModelInputError

__all__ = ["REQUIRED_KEYS", "DIVERGENCE_DIAMETERS", "DIVERGENCE_MIN_M", "compute_metrics", "divergence_bound_m",
           "diverged_at", "run_status", "status_line", "metrics_window_note", "headline"]

#: The divergence bound: this many vessel diameters from the reference, and never less than :data:`DIVERGENCE_MIN_M`.
DIVERGENCE_DIAMETERS = 10.0
DIVERGENCE_MIN_M = 10e-3

REQUIRED_KEYS = (
    "t_s",
    "p_true",
    "v_true",
    "p_ref",
    "x_hat",
    "z_hat",
    "g_applied",
    "saturated",
    "slew_limited",
    "in_contact",
)


def _norm_rows(a: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return np.sqrt(np.sum(a * a, axis=1))


def _max_rms(e: npt.NDArray[np.float64]) -> tuple[float, float]:
    # NaN marks a missing sample (a real-time run has no per-tick guarantee): left out
    finite = np.isfinite(e)
    if not finite.all():  # (every sample finite: e itself, without the copy)
        e = e[finite]
    if e.size == 0:
        return float("nan"), float("nan")
    return float(np.max(e)), float(np.sqrt(np.mean(e * e)))


def divergence_bound_m(vessel_diameter_m: float = 0.0) -> float:
    """How far from the reference the bead or its estimate may be before the run counts as diverged (m)."""
    d = float(vessel_diameter_m) if math.isfinite(vessel_diameter_m) else 0.0
    return max(DIVERGENCE_DIAMETERS * d, DIVERGENCE_MIN_M)


def diverged_at(t_s: npt.ArrayLike, p_true: npt.ArrayLike, x_hat: npt.ArrayLike, p_ref: npt.ArrayLike,
                bound_m: float, nonfinite_diverges: bool = False,
                true_dist: npt.NDArray[np.float64] | None = None) -> tuple[float, str] | None:
    """``(t, what)`` of the first tick at which the run diverged (module docstring), or None.

    Args:
        t_s: (n,) tick times, s.
        p_true, x_hat, p_ref: (n, d) true, estimated and reference positions, m.
        bound_m: :func:`divergence_bound_m`.
        nonfinite_diverges: A NaN counts (every tick was computed); an infinity always counts.
        true_dist: ``_norm_rows(p_true - p_ref)`` if the caller has it already (the tracking error).
    """
    t = np.asarray(t_s, dtype=np.float64)
    ref = np.asarray(p_ref, dtype=np.float64)
    first: tuple[float, str] | None = None
    for name, arr, known in (("the true position", p_true, true_dist), ("the estimate", x_hat, None)):
        a = np.asarray(arr, dtype=np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            dist = _norm_rows(a - ref) if known is None else known
            far = dist > bound_m
        if np.isfinite(a).all():  # no value is NaN or infinite (a finished run's usual case): distances decide
            bad_value = None
            hits = np.flatnonzero(far)
        else:
            bad_value = np.any(np.isinf(a), axis=1)
            if nonfinite_diverges:
                bad_value |= np.any(np.isnan(a), axis=1)
            hits = np.flatnonzero(far | bad_value)
        if hits.size == 0:
            continue
        k = int(hits[0])
        what = (f"{name} is not finite" if bad_value is not None and bad_value[k] else
                f"{name} is {float(dist[k]) * 1e3:.4g} mm from the reference")
        if first is None or float(t[k]) < first[0]:
            first = (float(t[k]), f"{what} (the bound is {bound_m * 1e3:g} mm)")
    return first


def run_status(metrics: Mapping[str, Any]) -> str:
    """The run's outcome: ``diverged``, ``rejected_commands`` (commands the coil refused) or ``ok``."""
    if metrics.get("diverged_at_s") is not None:
        return "diverged"
    if int(metrics.get("rejected_commands", 0) or 0) > 0:
        return "rejected_commands"
    return "ok"


def status_line(metrics: Mapping[str, Any]) -> str | None:
    """One warning line for a run whose status is not ``ok`` (None when it is)."""
    status = metrics.get("status", run_status(metrics))
    if status == "ok":
        return None
    if status == "diverged":
        return (f"warning: the run diverged at t = {float(metrics['diverged_at_s']):.4g} s: "
                f"{metrics.get('divergence') or 'beyond the divergence bound'}; its metrics are not a result")
    return f"warning: the run's status is {status}"


def compute_metrics(timeseries: Mapping[str, Any], after_s: float = 0.6, *, vessel_diameter_m: float = 0.0,
                    nonfinite_diverges: bool = False) -> dict[str, Any]:
    """Compute the closed-loop metrics (see module docstring for keys and units).

    Args:
        timeseries: Mapping with at least :data:`REQUIRED_KEYS`.
        after_s: Start of the steady-state window (s); paper: 0.6.
        vessel_diameter_m: The vessel's diameter (m), for :func:`divergence_bound_m`.
        nonfinite_diverges: A NaN position or estimate is a divergence (a run that computes every tick),
            not a missing sample.

    Returns:
        Dict of metrics.  If no tick lies at or after ``after_s`` (a run
        shorter than the window start) the window metrics cover the whole run
        and ``after_s`` is the first tick time (see :func:`metrics_window_note`).
        Rows holding NaN (a sample that never arrived, in a real-time run) are
        left out of the error and gradient statistics.

    Raises:
        ModelInputError: on a missing key or inconsistent lengths.
    """
    missing = [k for k in REQUIRED_KEYS if k not in timeseries]
    if missing:
        raise ModelInputError(f"timeseries lacks key(s) {missing}; required: {list(REQUIRED_KEYS)}")
    t = np.asarray(timeseries["t_s"], dtype=np.float64)
    n = t.size
    arrs = {k: np.asarray(timeseries[k]) for k in REQUIRED_KEYS}
    for k, a in arrs.items():
        if a.shape[0] != n:
            raise ModelInputError(f"timeseries[{k!r}] has {a.shape[0]} rows, expected {n} (len of t_s)")
    if n < 2:
        raise ModelInputError(f"timeseries needs at least 2 ticks, got {n}")
    dt = float(np.median(np.diff(t)))
    win = t >= after_s - 1e-12
    window_start = float(after_s)
    if not np.any(win):  # the run ends before the window starts: report over the run
        win = np.ones(n, dtype=bool)
        window_start = float(t[0])
    p = arrs["p_true"].astype(np.float64)
    e_track = _norm_rows(p - arrs["p_ref"].astype(np.float64))
    e_est = _norm_rows(arrs["x_hat"].astype(np.float64) - p)
    e_vel = _norm_rows(arrs["z_hat"].astype(np.float64) - arrs["v_true"].astype(np.float64))
    tr_max, tr_rms = _max_rms(e_track[win])
    es_max, es_rms = _max_rms(e_est[win])
    ev_max, ev_rms = _max_rms(e_vel[win])
    contact = arrs["in_contact"].astype(bool)
    onsets = int(contact[0]) + int(np.count_nonzero(contact[1:] & ~contact[:-1]))
    slew = arrs["slew_limited"].astype(bool)
    if slew.ndim == 2:  # any axis slew-limited: the columns or'ed one by one (faster than np.any(axis=1))
        any_axis = np.zeros(slew.shape[0], dtype=bool)
        for c in range(slew.shape[1]):
            any_axis |= slew[:, c]
        slew = any_axis
    out: dict[str, Any] = {
        "after_s": window_start,
        "duration_s": float(t[-1] - t[0] + dt),
        "n_ticks": int(n),
        "tracking_error_max_m": tr_max,
        "tracking_error_rms_m": tr_rms,
        "tracking_error_max_all_m": _max_rms(e_track)[0],
        "estimation_error_max_m": es_max,
        "estimation_error_rms_m": es_rms,
        "velocity_estimation_error_max_m_per_s": ev_max,
        "velocity_estimation_error_rms_m_per_s": ev_rms,
        "saturation_time_s": float(np.count_nonzero(arrs["saturated"].astype(bool)) * dt),
        "slew_limited_time_s": float(np.count_nonzero(slew) * dt),
        "wall_contacts": onsets,
        "contact_time_s": float(np.count_nonzero(contact) * dt),
        "max_gradient_T_per_m": _max_rms(_norm_rows(arrs["g_applied"].astype(np.float64)))[0],
    }
    if "cmd_rejected" in timeseries:  # optional: the loops' rejection codes, or a bag's coil.rejected flags
        codes = np.asarray(timeseries["cmd_rejected"])
        if codes.shape[:1] != (n,):
            raise ModelInputError(f"timeseries['cmd_rejected'] has shape {codes.shape}, expected {n} rows (len of t_s)")
        rej: npt.NDArray[np.bool_] = np.any(codes.reshape(n, -1).astype(bool), axis=1)
        out["rejected_commands"] = int(np.count_nonzero(rej))
        if out["rejected_commands"]:
            out["first_rejected_command_s"] = float(t[np.argmax(rej)])
    div = diverged_at(t, p, arrs["x_hat"], arrs["p_ref"], divergence_bound_m(vessel_diameter_m), nonfinite_diverges,
                      true_dist=e_track)
    out["diverged_at_s"] = None if div is None else div[0]
    out["divergence"] = None if div is None else div[1]
    out["status"] = run_status(out)
    return out


def metrics_window_note(metrics: Mapping[str, Any], requested_after_s: float) -> str | None:
    """One line saying that the metrics window had to change, or None if it did not.

    Args:
        metrics: The result of :func:`compute_metrics`.
        requested_after_s: The ``after_s`` that was asked for (``sim.metrics_after_s``).
    """
    if abs(float(metrics["after_s"]) - float(requested_after_s)) <= 1e-12:
        return None
    return (f"note: the run ({float(metrics['duration_s']):g} s) ends before the metrics window starts "
            f"(sim.metrics_after_s = {float(requested_after_s):g} s); the window metrics cover the whole run")


def _um(x_m: Any) -> str:
    return "-" if x_m is None or not math.isfinite(float(x_m)) else f"{float(x_m) * 1e6:.1f} um"


def headline(metrics: Mapping[str, Any]) -> str:
    """The run's result in one line a person reads: the errors in um, saturation, contacts (simulate and run).

    ``tracking error after 0.6 s max 751.2 um rms 310.4 um; estimation error max 402.0 um; saturated 0.120 s;
    contacts 0``, with ``; rejected commands N``, ``; frames rejected N of M (reasons)`` (an imager that tracks
    its own frames) and ``; diverged at t = T s`` when they apply.  Every metric,
    in SI units, is in ``metrics.json`` (``simulate``) or ``--metrics-json`` (``run``).
    """
    m = metrics  # a metric missing (a partial mapping) reads "-", as one that does not apply
    after = "-" if m.get("after_s") is None else f"{float(m['after_s']):g} s"
    sat = "-" if m.get("saturation_time_s") is None else f"{float(m['saturation_time_s']):.3f} s"
    text = (f"tracking error after {after} max {_um(m.get('tracking_error_max_m'))} "
            f"rms {_um(m.get('tracking_error_rms_m'))}; estimation error max {_um(m.get('estimation_error_max_m'))}; "
            f"saturated {sat}; contacts {m.get('wall_contacts', '-')}")
    if int(m.get("rejected_commands", 0) or 0) > 0:
        text += f"; rejected commands {int(m['rejected_commands'])}"
    if int(m.get("imager_frames_rejected", 0) or 0) > 0:
        text += (f"; frames rejected {int(m['imager_frames_rejected'])} of {int(m.get('imager_frames', 0))} "
                 f"({m.get('imager_rejected_reasons', '')})")
    if m.get("diverged_at_s") is not None:
        text += f"; diverged at t = {float(m['diverged_at_s']):.4g} s"
    return text
