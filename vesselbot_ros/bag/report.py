"""Figures and metrics of a run computed from its bag alone (paper Figs. 9 and 10).

:func:`write_report` reads a bag (:func:`~vesselbot_ros.bag.reader.read_timeseries`),
aligns the per-tick topics on their stamps, computes the metrics with the
*same* function as the ROS-free runner
(:func:`vesselbot_ros.sim.metrics.compute_metrics`) and writes, into
``<bag>.report/`` beside the bag by default (:func:`vesselbot_ros.bag.derived_dir`: the bag folder
holds the bag only):

* ``fig9a_trajectory.png``: XZ trajectory, reference, estimate, the vessel's
  wall envelope over the run and its walls at the narrowest moment, time
  marks every 0.25 s (in a vessel network: the network, the branch reached;
  in a 3-D tree, :func:`tree_trajectory`: two projections, XZ as the paper's
  and XY from above, of its tubes and the three paths, y included);
* ``fig9b_errors.png``: tracking and estimation error (um, log scale) with the
  paper's 150 um and 10 um bounds and the start of the metrics window;
* ``fig10a_gradients.png``: |U| commanded and applied against U_sat (the
  limit is on the norm), and |dU/dt| per axis against the slew limit;
* ``fig10b_velocities.png``: true and estimated velocities;
* ``fig10c_velocity_error.png``: velocity estimation error;
* ``forces.png``: the force breakdown of eq. (1) over time;
* ``metrics.json``: the metrics plus bag facts (scenario, seed, counts,
  intervals of saturation, slew limiting and faults).

A 3-D tree's bag (its run metadata says ``dims: 3``, as ``vesselbot run``
records it) is read on (x, y, z): its metrics are the launcher's (errors in
space) and its per-axis plots have y.

Every time plot shades saturated intervals (red, full height), and marks
slew-limited (orange strip along the bottom), fault (grey strip along the
top) and rejected-command (purple strip just below it: the coil rejected the
controller's command and ramped towards zero) intervals, so that no shading
hides another.  The commanded gradient is drawn as commanded: a rejected
command is a gap, not the zero the driver records; ``metrics.json`` counts
them (``rejected_commands``, ``first_rejected_command_s``).  With a multiplexed
scanner sequence it also shades the tracking windows (light blue, full
height) read from the bag's sequence-phase topic (:func:`tracking_windows`):
no propulsion gradient is applied there, and the frames are acquired there.  Faults are the imager's scheduled outlier bursts and
dropouts from the run's config, those it announced on ``/diagnostics``, and
outlier frames detected in the bag: fresh measurements farther from the
true position at their acquisition time than ``max(10 um, median + 10 MAD)``
of all fresh frames' distances (a robust bound that noise alone does not
cross).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros import graph_spec
from vesselbot_ros.atomic_io import check_output_dir, save_figure, write_text
from vesselbot_ros.bag import derived_dir
from vesselbot_ros.bag.info import coverage_of_ticks
from vesselbot_ros.bag.reader import BagInfo, final_diagnostics, iter_messages, open_bag, read_timeseries
from vesselbot_ros.config import ConfigError, load_dataclass
from vesselbot_ros.control.route import draw_network, navigation_outcome, pulsation_of
from vesselbot_ros.errors import BagError
from vesselbot_ros.graph_spec import NODE_NAMES
from vesselbot_ros.imaging.imager_params import MrImagerParams
from vesselbot_ros.physics.axes import AXES, AXIS_INDEX
from vesselbot_ros.physics.params import BloodParams, FlowParams
from vesselbot_ros.scanner.actuator_limits import CoilLimits
from vesselbot_ros.scanner.sequence import PHASE_CODES
from vesselbot_ros.sim.metrics import compute_metrics, metrics_window_note
from vesselbot_ros.vessels.network import load_network
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

__all__ = ["write_report", "report_dir", "metrics_timeseries", "positions_3d", "tree_trajectory",
           "bool_intervals", "tracking_windows", "detect_outlier_frames", "diagnostic_counters",
           "DIAGNOSTIC_COUNTERS", "FIGURES", "fig9a_trajectory", "fig9b_errors", "fig10a_gradients",
           "fig10b_velocities", "fig10c_velocity_error", "forces_figure"]

TRACKING_BOUND_M = 150e-6  # paper Fig. 9b: tracking error bound after 0.6 s
ESTIMATION_BOUND_M = 10e-6  # paper Fig. 9b: estimation error bound
FIGURES = ("fig9a_trajectory.png", "fig9b_errors.png", "fig10a_gradients.png", "fig10b_velocities.png",
           "fig10c_velocity_error.png", "forces.png")
#: Room a report needs at most (six figures of 0.1 to 0.5 MiB each and metrics.json), bytes.
REPORT_BYTES = 8 * 2**20


def bool_intervals(t_s: npt.NDArray[np.float64], flag: npt.NDArray[np.bool_]) -> list[tuple[float, float]]:
    """Maximal [start, end) intervals where ``flag`` holds; each tick lasts until the next one.

    Args:
        t_s: (n,) increasing tick times, s.
        flag: (n,) booleans.

    Returns:
        List of (start_s, end_s); the last tick lasts one median tick period.
    """
    t = np.asarray(t_s, dtype=np.float64)
    f = np.asarray(flag, dtype=bool)
    if t.size == 0 or not f.any():
        return []
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    t_end = np.append(t[1:], t[-1] + dt)
    edges = np.diff(np.concatenate([[0], f.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(t_end[b])) for a, b in zip(starts, ends)]


def _align(ts: Mapping[str, np.ndarray], prefixes: tuple[str, ...]) -> dict[str, npt.NDArray[np.intp]]:
    """Row indices of each prefix's topic for the stamps present in all of them (first message per stamp)."""
    keys = []
    for p in prefixes:
        t = ts.get(f"{p}.t_s")
        if t is None or len(t) == 0:
            raise BagError(f"the bag has no messages for {p!r}; the report needs truth, reference, estimate "
                           f"and coil state")
        ns = np.round(np.asarray(t) * 1e9).astype(np.int64)
        uniq, first = np.unique(ns, return_index=True)
        keys.append((uniq, first))
    common = keys[0][0]
    for uniq, _ in keys[1:]:
        common = np.intersect1d(common, uniq)
    out = {}
    for p, (uniq, first) in zip(prefixes, keys):
        out[p] = first[np.searchsorted(uniq, common)]
    out["_ns"] = common
    return out


def metrics_timeseries(ts: Mapping[str, np.ndarray], dt_s: float | None = None, dims: int = 2) -> dict[str, np.ndarray]:
    """The per-tick series :func:`vesselbot_ros.sim.metrics.compute_metrics` takes, from bag arrays.

    Ticks are the stamps present on ``truth``, ``reference``, ``estimate`` and
    ``coil`` state; vectors keep (x, z), or (x, y, z) for a 3-D tree (``dims`` 3).

    Args:
        ts: Arrays from :func:`~vesselbot_ros.bag.reader.read_timeseries`.
        dt_s: Control period (s).  Given, tick times are rebuilt as ``k * dt_s``
            with ``k`` recovered from the stamp (the graph's convention, so the
            metrics equal the launcher's bit for bit); None: ``stamp * 1e-9``.
        dims: Axes of the run (``Scenario.dims``).

    Raises:
        BagError: if one of those topics is missing or empty.
    """
    idx = _align(ts, ("truth", "reference", "estimate", "coil"))
    tr, rf, es, co = idx["truth"], idx["reference"], idx["estimate"], idx["coil"]
    if dt_s is not None:
        t_s = np.round(idx["_ns"] * 1e-9 / dt_s).astype(np.int64) * dt_s
    else:
        t_s = idx["_ns"].astype(np.float64) * 1e-9
    ax = list(AXIS_INDEX[dims])
    rej = ts.get("coil.rejected")
    rejected = (np.asarray(rej)[co].astype(bool) if rej is not None and len(rej)
                else np.zeros(len(co), dtype=bool))
    return {
        "t_s": t_s,
        "p_true": ts["truth.p_WR"][tr][:, ax],
        "v_true": ts["truth.v_WR"][tr][:, ax],
        "p_ref": ts["reference.p_ref"][rf][:, ax],
        "x_hat": ts["estimate.p_hat"][es][:, ax],
        "z_hat": ts["estimate.v_hat"][es][:, ax],
        "g_applied": ts["coil.applied"][co][:, ax],
        # as commanded: a command the coil rejected is NaN (a gap in the figure), never the 0 the driver records
        "g_cmd": np.where(rejected[:, None], np.nan, ts["coil.commanded"][co][:, ax]),
        "cmd_rejected": rejected,
        "saturated": ts["coil.saturated"][co].astype(bool),
        "slew_limited": np.stack([ts[f"coil.slew_limited_{c}"][co] for c in AXES[dims]], axis=1).astype(bool),
        "in_contact": ts["truth.in_contact"][tr].astype(bool),
        "diameter_m": ts["truth.diameter_m"][tr],
        "max_gradient": ts["coil.max_gradient"][co],
        "forces": np.stack([ts[f"truth.F_{k}"][tr][:, ax] for k in
                            ("magnetic", "drag", "apparent_weight", "contact", "van_der_waals", "electrostatic",
                             "steric", "total")], axis=1),
    }


def positions_3d(ts: Mapping[str, np.ndarray]) -> dict[str, npt.NDArray[np.float64]]:
    """(n, 3) positions (x, y, z) of the robot, the reference and the estimate on :func:`metrics_timeseries`'s ticks.

    The same rows as its ``p_true``, ``p_ref`` and ``x_hat``, which keep (x, z): a 3-D run's y is here.
    """
    idx = _align(ts, ("truth", "reference", "estimate", "coil"))
    return {"p_true": ts["truth.p_WR"][idx["truth"]], "p_ref": ts["reference.p_ref"][idx["reference"]],
            "x_hat": ts["estimate.p_hat"][idx["estimate"]]}


def detect_outlier_frames(ts: Mapping[str, np.ndarray], dims: int = 2) -> tuple[npt.NDArray[np.float64], float]:
    """Acquisition times (s) of fresh measurements far from the truth, and the threshold used (m).

    The distance is ``|p_meas - p_true(t_acq)|`` in the xz plane (in space for a 3-D tree, ``dims`` 3), the truth
    interpolated at the acquisition stamp; the threshold is
    ``max(10 um, median + 10 * MAD)`` over all fresh frames.
    """
    if "measurement.t_s" not in ts or "truth.t_s" not in ts or len(ts["measurement.t_s"]) == 0:
        return np.zeros(0), float("nan")
    fresh = ts["measurement.fresh"].astype(bool)
    t_m = ts["measurement.t_s"][fresh]
    p_m = ts["measurement.p_meas"][fresh][:, list(AXIS_INDEX[dims])]
    t_tr = ts["truth.t_s"]
    order = np.argsort(t_tr, kind="stable")
    p_tr = np.stack([np.interp(t_m, t_tr[order], ts["truth.p_WR"][order][:, a]) for a in AXIS_INDEX[dims]], axis=1)
    d = np.linalg.norm(p_m - p_tr, axis=1)
    if d.size == 0:
        return np.zeros(0), float("nan")
    med = float(np.median(d))
    mad = float(np.median(np.abs(d - med)))
    thr = max(10e-6, med + 10.0 * mad)
    return t_m[d > thr], thr


def _fault_intervals(ts: Mapping[str, np.ndarray], run: Mapping[str, Any], dt: float,
                     dims: int = 2) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    imager = (run.get("config") or {}).get("imager") or {}
    for o in imager.get("outliers") or []:
        out.append({"kind": "outlier_burst", "source": "config", "start_s": float(o.get("start_s", 0.5)),
                    "end_s": float(o.get("start_s", 0.5)) + float(o.get("duration_s", 0.02))})
    for d in imager.get("dropouts") or []:
        out.append({"kind": "dropout", "source": "config", "start_s": float(d.get("start_s", 1.0)),
                    "end_s": float(d.get("start_s", 1.0)) + float(d.get("duration_s", 0.1))})
    for t0, kind, dur in zip(ts.get("faults.t_s", []), ts.get("faults.kind", []), ts.get("faults.duration_s", [])):
        out.append({"kind": str(kind), "source": "diagnostics", "start_s": float(t0),
                    "end_s": float(t0) + (float(dur) if math.isfinite(float(dur)) else dt)})
    t_out, _thr = detect_outlier_frames(ts, dims)
    for a, b in bool_intervals(t_out, np.ones(t_out.size, bool)) if t_out.size > 1 else [
            (float(t), float(t) + dt) for t in t_out]:
        out.append({"kind": "outlier_frames", "source": "detected", "start_s": a, "end_s": max(b, a + dt)})
    return out


def tracking_windows(ts: Mapping[str, np.ndarray], t_end_s: float) -> list[tuple[float, float]]:
    """The scanner's tracking windows ``[start, end)`` recorded on the sequence-phase topic, clipped to ``t_end_s``.

    Empty for a continuous sequence (the paper's loop) and for bags without the topic.
    """
    phase = np.asarray(ts.get("phase.phase", np.zeros(0)))
    if phase.size == 0:
        return []
    sel = phase == PHASE_CODES["tracking"]
    starts = np.asarray(ts["phase.window_start_s"])[sel]
    ends = np.asarray(ts["phase.window_end_s"])[sel]
    return [(float(a), float(min(b, t_end_s))) for a, b in zip(starts, ends, strict=True) if a < t_end_s]


def _shade(ax: Any, spans: Mapping[str, list[tuple[float, float]]]) -> None:
    """Saturation over the full height; slew limiting and faults as strips along the bottom and top edge.

    The strips never cover the saturation shading, even when the coil is
    slew-limited for the whole run.
    """
    style = {"saturated": ("tab:red", 0.15, 0.0, 1.0), "slew limited": ("tab:orange", 0.6, 0.0, 0.05),
             "fault": ("0.3", 0.6, 0.95, 1.0), "tracking window": ("tab:blue", 0.1, 0.0, 1.0),
             "rejected command": ("tab:purple", 0.6, 0.9, 0.95)}
    for label, ivs in spans.items():
        color, alpha, lo, hi = style[label]
        for i, (a, b) in enumerate(ivs):
            ax.axvspan(a, b, ymin=lo, ymax=hi, color=color, alpha=alpha, lw=0, label=label if i == 0 else None)


def _slew_limit(run: Mapping[str, Any]) -> float | None:
    """The coil's slew limit (T/m/s) from the run's config, or None."""
    coil = (run.get("config") or {}).get("coil")
    if not isinstance(coil, Mapping):
        return None
    try:
        return float(load_dataclass(CoilLimits, coil, "coil").slew_rate_T_per_m_per_s)
    except (ConfigError, TypeError, ValueError):
        return None


def _run_physics(run: Mapping[str, Any], section: str, cls: Any) -> Any:
    """The run's ``physics.<section>`` loaded as ``cls`` from its config, or None (missing or not loadable)."""
    mapping = ((run.get("config") or {}).get("physics") or {}).get(section)
    if not isinstance(mapping, Mapping):
        return None
    try:
        return load_dataclass(cls, mapping, f"physics.{section}")
    except (ConfigError, TypeError, ValueError):
        return None


def _run_blood(run: Mapping[str, Any]) -> Any:
    """The run's blood model (``BloodParams``) from its config, or None (then the shipped scenarios' default)."""
    return _run_physics(run, "blood", BloodParams)


def _run_pulsation(run: Mapping[str, Any]) -> tuple[float, float, float] | None:
    """The wall's eq. (13) pulsation of the run's flow (:func:`~vesselbot_ros.control.route.pulsation_of`), from its
    config; None (the wall at rest) without one."""
    flow = _run_physics(run, "flow", FlowParams)
    return None if flow is None else pulsation_of(flow)


def _time_marks(t: npt.NDArray[np.float64], step_s: float = 0.25) -> npt.NDArray[np.intp]:
    """Indices of the ticks nearest to 0, step, 2 step, ... within the run."""
    marks = np.arange(math.ceil(t[0] / step_s) * step_s, t[-1] + 1e-12, step_s)
    return np.unique(np.clip(np.searchsorted(t, marks - 1e-12), 0, t.size - 1))


def fig9a_trajectory(t: npt.NDArray[np.float64], m: Mapping[str, np.ndarray]) -> Any:
    """Fig. 9a: XZ trajectory, reference and estimate in the vessel, with time marks.

    The vessel is a straight tube whose diameter D(t) pulsates in time, the
    same at every x.  It is drawn as the envelope of its walls over the run
    (shaded, D_min to D_max) and its walls at the narrowest moment (solid
    lines, the time is in the legend), across the whole x range of the
    trajectory and the reference.  Dots on the trajectory and the reference
    mark every 0.25 s.
    """
    import matplotlib.pyplot as plt  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    mm = 1e3
    fig, ax = plt.subplots(figsize=(8, 4))
    d = np.asarray(m["diameter_m"], dtype=np.float64)
    xs = np.concatenate([m["p_true"][:, 0], m["p_ref"][:, 0], m["x_hat"][:, 0]]) * mm
    xs = xs[np.isfinite(xs)]
    x_lo, x_hi = float(xs.min()), float(xs.max())
    pad = 0.03 * max(x_hi - x_lo, 1e-6)
    xe = np.array([x_lo - pad, x_hi + pad])
    d_min, d_max = float(np.nanmin(d)), float(np.nanmax(d))
    k_min = int(np.nanargmin(d))
    outer = d_max / 2 * 1.15 * mm
    for sgn in (1, -1):
        ax.fill_between(xe, sgn * d_max / 2 * mm, sgn * outer, color="0.8", lw=0,
                        label="vessel wall" if sgn > 0 else None)
        ax.fill_between(xe, sgn * d_min / 2 * mm, sgn * d_max / 2 * mm, color="0.9", lw=0,
                        label=f"wall motion over the run (D = {d_min * mm:.3g} to {d_max * mm:.3g} mm)"
                        if sgn > 0 else None)
        ax.plot(xe, [sgn * d_min / 2 * mm] * 2, color="0.35", lw=1.0,
                label=f"walls at t = {t[k_min]:.3g} s (narrowest)" if sgn > 0 else None)
    ax.plot(m["p_ref"][:, 0] * mm, m["p_ref"][:, 1] * mm, "k--", lw=1.2, label="reference")
    ax.plot(m["p_true"][:, 0] * mm, m["p_true"][:, 1] * mm, "tab:blue", lw=1.2, label="robot (truth)")
    ax.plot(m["x_hat"][:, 0] * mm, m["x_hat"][:, 1] * mm, "tab:green", lw=0.8, alpha=0.8, label="estimate")
    idx = _time_marks(t)
    ax.plot(m["p_true"][idx, 0] * mm, m["p_true"][idx, 1] * mm, "o", color="tab:blue", ms=4,
            label="every 0.25 s")
    ax.plot(m["p_ref"][idx, 0] * mm, m["p_ref"][idx, 1] * mm, "o", color="k", ms=3, mfc="none")
    for k in idx:
        ax.annotate(f"{t[k]:g} s", (m["p_true"][k, 0] * mm, m["p_true"][k, 1] * mm), textcoords="offset points",
                    xytext=(3, 5), fontsize=7, color="tab:blue")
    ax.set_xlim(*xe)
    ax.set(xlabel="x (mm)", ylabel="z (mm)", title="Fig. 9a: trajectory in the vessel (XZ)")
    ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    return fig


def fig9b_errors(t: npt.NDArray[np.float64], m: Mapping[str, np.ndarray],
                 spans: Mapping[str, list[tuple[float, float]]], after_s: float) -> Any:
    """Fig. 9b: tracking and estimation error (um, log scale), the paper's bounds, the metrics window.

    The axis spans the errors after the first ticks (down to at most 1 um),
    not the exact zero of t = 0.
    """
    import matplotlib.pyplot as plt  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    um = 1e6
    e_tr = np.linalg.norm(m["p_true"] - m["p_ref"], axis=1) * um
    e_es = np.linalg.norm(m["x_hat"] - m["p_true"], axis=1) * um
    fig, ax = plt.subplots(figsize=(8, 4))
    _shade(ax, spans)
    ax.semilogy(t, np.where(e_tr > 0, e_tr, np.nan), "tab:blue", lw=1, label="tracking error |p - p_ref|")
    ax.semilogy(t, np.where(e_es > 0, e_es, np.nan), "tab:green", lw=1, label="estimation error |p_hat - p|")
    ax.axhline(TRACKING_BOUND_M * um, color="tab:blue", ls=":", label="150 um bound (paper, tracking)")
    ax.axhline(ESTIMATION_BOUND_M * um, color="tab:green", ls=":", label="10 um bound (paper, estimation)")
    ax.axvline(after_s, color="k", ls="--", lw=0.8, label=f"metrics window starts ({after_s:g} s)")
    body = t >= t[0] + 0.02 * (t[-1] - t[0])  # leave out the start, where the errors are exactly 0
    vals = np.concatenate([e_tr[body], e_es[body]])
    vals = vals[np.isfinite(vals) & (vals > 0)]
    lo = min(1.0, float(np.percentile(vals, 1)) / 2) if vals.size else 1.0
    hi = max(2 * TRACKING_BOUND_M * um, 2 * float(vals.max())) if vals.size else 2 * TRACKING_BOUND_M * um
    ax.set_ylim(lo, hi)
    ax.set(xlabel="t (s)", ylabel="error (um)", title="Fig. 9b: tracking and estimation error")
    ax.legend(loc="best", fontsize=7)
    fig.tight_layout()
    return fig


def fig10a_gradients(t: npt.NDArray[np.float64], m: Mapping[str, np.ndarray],
                     spans: Mapping[str, list[tuple[float, float]]], slew_limit_T_per_m_per_s: float | None) -> Any:
    """Fig. 10a: |U| against U_sat (the limit is on the Euclidean norm) and dU/dt against the slew limit.

    Top: ``|U|`` commanded and applied, and ``U_sat``.  Bottom: ``|dU_x/dt|``
    and ``|dU_z/dt|`` of the applied gradient (the slew limit is per axis)
    and the slew limit from the run's config (if the bag says).
    """
    import matplotlib.pyplot as plt  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    mm = 1e3
    fig, axs = plt.subplots(2, 1, sharex=True, figsize=(8, 5.5))
    a = axs[0]
    _shade(a, spans)
    # a rejected command is NaN: a gap in the commanded line, over the "rejected command" strip
    a.plot(t, np.linalg.norm(m["g_cmd"], axis=1) * mm, "tab:gray", lw=0.8, label="|U| commanded")
    a.plot(t, np.linalg.norm(m["g_applied"], axis=1) * mm, "tab:red", lw=1.0, label="|U| applied")
    a.plot(t, np.asarray(m["max_gradient"]) * mm, "k:", lw=1.0, label="U_sat (limit on |U|)")
    a.set_ylabel("|U| (mT/m)")
    a.set_title("Fig. 10a: gradient norm vs saturation, rate vs slew limit")
    a.legend(loc="best", fontsize=7)
    b = axs[1]
    _shade(b, spans)
    dt = np.diff(t)
    rate = np.abs(np.diff(m["g_applied"], axis=0)) / dt[:, None] * mm
    for i, axis in enumerate(_axis_names(m)):
        b.plot(t[1:], rate[:, i], lw=0.8, label=f"|dU_{axis}/dt| applied")
    if slew_limit_T_per_m_per_s is not None:
        b.axhline(slew_limit_T_per_m_per_s * mm, color="k", ls=":", lw=1.0,
                  label=f"slew limit ({slew_limit_T_per_m_per_s:g} T/m/s per axis)")
    b.set_ylabel("|dU/dt| (mT/m/s)")
    b.set_xlabel("t (s)")
    b.legend(loc="best", fontsize=7)
    fig.tight_layout()
    return fig


def fig10b_velocities(t: npt.NDArray[np.float64], m: Mapping[str, np.ndarray],
                      spans: Mapping[str, list[tuple[float, float]]]) -> Any:
    """Fig. 10b: true and estimated velocity per axis (mm/s)."""
    import matplotlib.pyplot as plt  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    mm = 1e3
    names = _axis_names(m)
    fig, axs = plt.subplots(len(names), 1, sharex=True, figsize=(8, 2.5 * len(names)))
    for i, axis in enumerate(names):
        a = axs[i]
        _shade(a, spans)
        a.plot(t, m["v_true"][:, i] * mm, "tab:blue", lw=1.0, label="true")
        a.plot(t, m["z_hat"][:, i] * mm, "tab:green", lw=0.8, label="estimated")
        a.set_ylabel(f"v_{axis} (mm/s)")
    axs[0].set_title("Fig. 10b: true and estimated velocity")
    axs[0].legend(loc="best", fontsize=8)
    axs[-1].set_xlabel("t (s)")
    fig.tight_layout()
    return fig


def fig10c_velocity_error(t: npt.NDArray[np.float64], m: Mapping[str, np.ndarray],
                          spans: Mapping[str, list[tuple[float, float]]]) -> Any:
    """Fig. 10c: velocity estimation error per axis (mm/s)."""
    import matplotlib.pyplot as plt  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    mm = 1e3
    fig, ax = plt.subplots(figsize=(8, 3.5))
    _shade(ax, spans)
    for i, axis in enumerate(_axis_names(m)):
        ax.plot(t, (m["z_hat"][:, i] - m["v_true"][:, i]) * mm, lw=1.0, label=f"v_hat_{axis} - v_{axis}")
    ax.set(xlabel="t (s)", ylabel="mm/s", title="Fig. 10c: velocity estimation error")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    return fig


FORCE_AXIS_DECADES = 6  # the force plot shows 6 decades below the largest term


def forces_figure(t: npt.NDArray[np.float64], m: Mapping[str, np.ndarray],
                  spans: Mapping[str, list[tuple[float, float]]]) -> Any:
    """Force breakdown of eq. (1) over time (log axis).

    The axis shows :data:`FORCE_AXIS_DECADES` decades below the largest term;
    a term that stays below them (e.g. van der Waals at 1e-16 N far from the
    wall) is named in the legend with its largest value instead of stretching
    the axis.
    """
    import matplotlib.pyplot as plt  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    names = ("magnetic", "drag", "apparent weight", "contact", "van der Waals", "electrostatic", "steric", "total")
    mags = [np.linalg.norm(m["forces"][:, k, :], axis=1) for k in range(len(names))]
    top = max((float(np.nanmax(f)) for f in mags if f.size and np.any(f > 0)), default=1.0)
    floor = top * 10.0**-FORCE_AXIS_DECADES
    fig, ax = plt.subplots(figsize=(8, 4.5))
    _shade(ax, spans)
    below = []
    for name, f in zip(names, mags):
        if not np.any(f > 0):
            continue
        if float(np.nanmax(f)) < floor:
            below.append(f"{name} (max {float(np.nanmax(f)):.1e} N)")
            continue
        ax.semilogy(t, np.where(f > 0, f, np.nan), lw=1.6 if name == "total" else 0.9,
                    ls="--" if name == "total" else "-", label=name)
    if below:
        ax.plot([], [], " ", label="below the axis: " + ", ".join(below))
    ax.set_ylim(floor, top * 3)
    ax.set(xlabel="t (s)", ylabel="|F| (N)", title="Force breakdown, eq. (1)")
    ax.legend(loc="best", fontsize=7, ncol=2)
    fig.tight_layout()
    return fig


#: Counters the launcher adds to the run's metrics from the nodes' final ``/diagnostics``
#: (node role -> keys); the plant's are ``plant_node.PLANT_STAT_NAMES`` (tested equal).
DIAGNOSTIC_COUNTERS: dict[str, tuple[str, ...]] = graph_spec.diagnostic_counters()


def _axis_names(m: Mapping[str, np.ndarray]) -> str:
    """The axes of a run's vectors: ``xz`` (planar) or ``xyz`` (a 3-D tree)."""
    return "".join(AXES[m["g_applied"].shape[1]])


def _run_dims(run: Mapping[str, Any]) -> int:
    """The axes of the run's vectors as ``vesselbot run`` recorded them (``dims``: 3 in a 3-D tree); 2 when the bag
    does not say (a planar run, or a bag from before 3-D trees)."""
    dims = run.get("dims")
    return dims if dims in AXES else 2


def _run_network(run: Mapping[str, Any]) -> tuple[str, str] | None:
    """(network file, target outlet) of a run in a vessel network, else None."""
    try:
        net = run["config"]["physics"]["vessel"].get("network", "")
    except (KeyError, TypeError, AttributeError):
        return None
    if not net:
        return None
    ref = (run.get("config") or {}).get("reference") or {}
    return str(net), str(ref.get("route_outlet", ""))


def network_trajectory(t: npt.NDArray[np.float64], m: Mapping[str, np.ndarray], network: str,
                       metrics: Mapping[str, Any]) -> Any:
    """Fig. 9a in a vessel network: the network, the trajectory, the reference and the estimate; the branch reached."""
    import matplotlib.pyplot as plt  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    mm = 1e3
    fig, ax = plt.subplots(figsize=(9, 5))
    draw_network(ax, network, mm)
    # x and z (the last column, also of a 3-D run's (x, y, z))
    ax.plot(m["p_ref"][:, 0] * mm, m["p_ref"][:, -1] * mm, "k--", lw=1.0, label="reference")
    ax.plot(m["x_hat"][:, 0] * mm, m["x_hat"][:, -1] * mm, color="tab:orange", lw=0.6, alpha=0.8, label="estimate")
    ax.plot(m["p_true"][:, 0] * mm, m["p_true"][:, -1] * mm, color="tab:blue", lw=1.2, label="robot")
    target = metrics.get("route_outlet") or "-"
    ok = "reached" if metrics.get("reached_target") else "NOT reached"
    ax.set_title(f"branch reached: {metrics.get('branch_final')} (target {target}: {ok}); "
                 f"outside the lumen {metrics.get('outside_lumen_time_s', 0.0):.3f} s")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_aspect("equal")
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    return fig


def _draw_tree_projection(ax: Any, geom: NetworkGeometry, axis: int, mm: float) -> None:
    """A 3-D tree's tubes projected on the plane of x and coordinate ``axis`` (1: y, 2: z): each a grey band.

    A tube's projection is its projected centreline widened by its radius on either side, across the projected
    direction (exact for a circular section; where a branch runs along the viewing direction the band
    narrows to its centreline, which is drawn dotted).
    """
    for name in geom.names:
        q = geom.centreline(name)[:, [0, axis]]
        rad = geom.radius(name)
        tan = np.gradient(q, axis=0)
        length = np.hypot(tan[:, 0], tan[:, 1])
        nrm = np.column_stack([-tan[:, 1], tan[:, 0]]) / np.maximum(length, 1e-300)[:, None]
        poly = np.concatenate([q + rad[:, None] * nrm, (q - rad[:, None] * nrm)[::-1]]) * mm
        ax.fill(poly[:, 0], poly[:, 1], color="0.88", lw=0, zorder=0)
        ax.plot(poly[:, 0], poly[:, 1], color="0.55", lw=0.5, zorder=1)
        ax.plot(*(q * mm).T, color="0.6", lw=0.5, ls=":", zorder=1)
        ax.annotate(name, tuple(q[-1] * mm), fontsize=7, color="0.3")


def tree_trajectory(t: npt.NDArray[np.float64], p: Mapping[str, np.ndarray], network: str,
                    metrics: Mapping[str, Any]) -> Any:
    """Fig. 9a in a 3-D vessel tree: XZ (the paper's plane) and XY (from above) projections of the tree and paths.

    ``p`` holds (n, 3) ``p_true``, ``p_ref`` and ``x_hat`` (:func:`positions_3d`).  Each panel draws the
    tubes (:func:`_draw_tree_projection`), the reference, the estimate and the robot, with dots every
    0.25 s, at equal scales on both axes and the tree's x range in both panels.
    """
    import matplotlib.pyplot as plt  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    mm = 1e3
    geom = NetworkGeometry(load_network(network), dims=3)
    fig, axs = plt.subplots(2, 1, figsize=(9, 9))
    idx = _time_marks(t)
    x_lo, x_hi = geom.bbox[0] * mm, geom.bbox[1] * mm
    for ax, axis in zip(axs, (2, 1)):
        _draw_tree_projection(ax, geom, axis, mm)
        ax.plot(p["p_ref"][:, 0] * mm, p["p_ref"][:, axis] * mm, "k--", lw=1.0, label="reference")
        ax.plot(p["x_hat"][:, 0] * mm, p["x_hat"][:, axis] * mm, color="tab:orange", lw=0.6, alpha=0.8,
                label="estimate")
        ax.plot(p["p_true"][:, 0] * mm, p["p_true"][:, axis] * mm, color="tab:blue", lw=1.2, label="robot")
        ax.plot(p["p_true"][idx, 0] * mm, p["p_true"][idx, axis] * mm, "o", color="tab:blue", ms=3,
                label="every 0.25 s")
        ax.set_xlim(x_lo - 0.02 * (x_hi - x_lo), x_hi + 0.02 * (x_hi - x_lo))
        ax.set_aspect("equal", adjustable="datalim")
        ax.set(xlabel="x (mm)", ylabel=f"{'xyz'[axis]} (mm)")
        ax.legend(loc="lower left", fontsize=7)
    outcome = ""
    if "branch_final" in metrics:
        target = metrics.get("route_outlet") or "-"
        ok = "reached" if metrics.get("reached_target") else "NOT reached"
        outcome = f"; branch reached: {metrics.get('branch_final')} (target {target}: {ok})"
    axs[0].set_title(f"Fig. 9a: trajectory in the 3-D tree {geom.net.name}, projected on XZ{outcome}", fontsize=9)
    axs[1].set_title("the same, projected on XY (from above)", fontsize=9)
    fig.tight_layout()
    return fig


#: The report's figure of an MR frame (a run with ``imager.kind: mr_images``), besides :data:`FIGURES`.
MR_FRAME_FIGURE = "mr_frame.png"


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def mr_frame_figure(info: BagInfo, run: Mapping[str, Any], ts: Mapping[str, np.ndarray]) -> Any | None:
    """The run's last MR frame (``imager/image``: the magnitude) with the bead's true position at its acquisition
    time and the tracked one (the measurement stamped with it) marked; None when the bag holds no frame.

    A slice is drawn as an image in the vessel's frame (mm); MS-SET's three projections as profiles along x, y
    and z, each with the true and tracked coordinate as lines.
    """
    name = graph_spec.topic("mr_image").name
    if name not in {tp.name for tp in info.topics} or run.get("config", {}).get("imager", {}).get("kind") != "mr_images":
        return None
    last = None
    for msg in iter_messages(info, topics=[name]):
        last = msg
    if last is None:
        return None
    img = last.decode()
    stamp = _stamp_ns(img)
    try:
        params = load_dataclass(MrImagerParams, run["config"]["imager"], "imager")
    except (ConfigError, KeyError, TypeError):
        return None
    imaging = params.imaging
    mag = np.frombuffer(bytes(img.data), dtype="<f4").reshape(img.height, img.width)
    centre = np.asarray(params.fov_centre_m, dtype=np.float64)
    t_true = np.asarray(ts.get("truth.t_s", np.zeros(0)))
    p_true = np.asarray(ts.get("truth.p_WR", np.zeros((0, 3))))
    true_xyz = p_true[int(np.argmin(np.abs(t_true - stamp * 1e-9)))] if t_true.size else None
    t_meas = np.asarray(ts.get("measurement.t_s", np.zeros(0)))
    p_meas = np.asarray(ts.get("measurement.p_meas", np.zeros((0, 3))))
    hit = np.flatnonzero(np.abs(t_meas - stamp * 1e-9) < 0.5e-9) if t_meas.size else np.zeros(0, dtype=np.intp)
    tracked = p_meas[hit[0]] if hit.size else None
    n = imaging.matrix
    mm = 1e3
    coords = (np.arange(n) - n / 2) * imaging.pixel_m
    import matplotlib.pyplot as plt  # deferred: matplotlib (see write_report)

    when = f"acquired at t = {stamp * 1e-9:.3f} s"
    if imaging.acquisition == "slice":
        fig, ax = plt.subplots(figsize=(6.5, 6))
        ro = 0 if imaging.readout_axis == "x" else 2
        pe = 2 if ro == 0 else 0
        ext = (float(centre[ro] + coords[0]) * mm, float(centre[ro] + coords[-1]) * mm,
               float(centre[pe] + coords[0]) * mm, float(centre[pe] + coords[-1]) * mm)
        ax.imshow(mag, origin="lower", extent=ext, cmap="gray", aspect="equal")
        for p, style, label in ((true_xyz, "g+", "true"), (tracked, "rx", "tracked")):
            if p is not None:
                ax.plot(p[ro] * mm, p[pe] * mm, style, ms=14, mew=2, label=f"{label} position")
        ax.set_xlabel(f"{'xyz'[ro]} (mm, readout)")
        ax.set_ylabel(f"{'xyz'[pe]} (mm, phase encode)")
        ax.legend(loc="upper right")
        ax.set_title(f"MR slice (magnitude), {when}")
    else:
        fig, axs = plt.subplots(3, 1, sharex=False, figsize=(8, 7))
        for a, ax in enumerate(axs):
            ax.plot((centre[a] + coords) * mm, mag[a], "k-", lw=1, label="projection (magnitude)")
            for p, style, label in ((true_xyz, "g-", "true"), (tracked, "r--", "tracked")):
                if p is not None:
                    ax.axvline(p[a] * mm, color=style[0], ls=style[1:], label=f"{label} {'xyz'[a]}")
            if true_xyz is not None:  # the artefact spans tens of millimetres; the view is wider still
                ax.set_xlim((true_xyz[a] - 0.025) * mm, (true_xyz[a] + 0.025) * mm)
            ax.set_xlabel(f"{'xyz'[a]} (mm)")
            ax.set_ylabel("|signal|")
            ax.legend(loc="upper right", fontsize=8)
        axs[0].set_title(f"MS-SET projections, {when}")
    if tracked is None:
        fig.text(0.01, 0.01, "this frame's measurement is not in the bag (rejected by the tracker)", fontsize=8)
    fig.tight_layout()
    return fig


def _run_config_value(run: Mapping[str, Any], section: str, key: str) -> float | None:
    try:
        v = float(run["config"][section][key])
    except (KeyError, TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def diagnostic_counters(info: BagInfo) -> dict[str, int]:
    """The launcher's extra metrics (plant/observer/imager counters) from the bag's final diagnostics."""
    final = final_diagnostics(info)
    out: dict[str, int] = {}
    for role, keys in DIAGNOSTIC_COUNTERS.items():
        d = final.get(NODE_NAMES[role], {})
        for key in keys:
            if key in d:
                try:
                    out[key] = int(d[key])
                except ValueError:
                    continue
    return out


def report_dir(bag_dir: str | Path, out_dir: str | Path | None = None) -> Path:
    """Where :func:`write_report` writes: ``out_dir``, else ``<bag_dir>.report`` beside the bag (never into it)."""
    return Path(out_dir) if out_dir is not None else derived_dir(bag_dir, "report")


def write_report(bag_dir: str | Path | BagInfo, out_dir: str | Path | None = None,
                 after_s: float | None = None) -> dict[str, Any]:
    """Write the figures and ``metrics.json`` of a recorded run; return the metrics.

    The metrics are those of ``vesselbot run`` for the same run: the same
    :func:`~vesselbot_ros.sim.metrics.compute_metrics` on the same per-tick
    values (tick times ``k * dt`` with dt from the run's config), plus the
    plant, observer and imager counters from the nodes' final diagnostics.

    Args:
        bag_dir: The bag directory (or a validated :class:`BagInfo`).
        out_dir: Output folder (default ``<bag_dir>.report``, beside the bag: :func:`report_dir`).
        after_s: Start of the steady-state window of the metrics (s); None:
            the run's ``sim.metrics_after_s``, else 0.6 (paper).

    Raises:
        BagError: if the bag is invalid, corrupt or lacks the graph's topics.
    """
    import matplotlib  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib (see above)

    info = bag_dir if isinstance(bag_dir, BagInfo) else open_bag(bag_dir)
    out = report_dir(info.path, out_dir)
    # before any work: a folder that cannot be written, or too little room for the figures, is one line
    check_output_dir(out, "report folder", need_bytes=REPORT_BYTES,
                     need_why=f"{len(FIGURES)} figures and metrics.json, at most")
    run = info.run_metadata
    rate = _run_config_value(run, "sim", "control_rate_Hz")
    if after_s is None:
        after_s = _run_config_value(run, "sim", "metrics_after_s")
        after_s = 0.6 if after_s is None else after_s
    if not (math.isfinite(after_s) and after_s >= 0):
        raise BagError(f"--after must be a finite time >= 0 s, got {after_s!r}")
    ts = read_timeseries(info)
    dims = _run_dims(run)
    m = metrics_timeseries(ts, dt_s=1.0 / rate if rate else None, dims=dims)
    t = m["t_s"]
    if t.size < 2:
        raise BagError(f"bag {info.path} holds {t.size} complete tick(s); the report needs at least 2")
    dt = float(np.median(np.diff(t)))
    metrics: dict[str, Any] = dict(compute_metrics(m, after_s=after_s))
    note = metrics_window_note(metrics, after_s)
    if note:
        metrics["metrics_window_note"] = note
    sat = bool_intervals(t, m["saturated"])
    slew = bool_intervals(t, np.asarray(m["slew_limited"].any(axis=1), dtype=np.bool_))
    faults = _fault_intervals(ts, info.run_metadata, dt, dims)
    tracking = tracking_windows(ts, float(t[-1]) + dt)
    rejected = bool_intervals(t, np.asarray(m["cmd_rejected"], dtype=np.bool_))
    spans = {"saturated": sat, "slew limited": slew, "fault": [(f["start_s"], f["end_s"]) for f in faults],
             "tracking window": tracking, "rejected command": rejected}
    t_out, thr = detect_outlier_frames(ts, dims)
    metrics.update(diagnostic_counters(info))
    # a repaired bag may end before the run did: the span it covers, against the run's planned duration
    cov = coverage_of_ticks(run, float(t[0]), float(t[-1]))
    metrics.update(cov.as_dict(), coverage=cov.line())
    metrics.update({
        "bag": str(info.path),
        "scenario": run.get("scenario"),
        "seed": run.get("seed"),
        "mode": run.get("mode"),
        "message_counts": {tp.name: tp.count for tp in info.topics},
        "saturated_intervals_s": sat,
        "slew_limited_intervals_s": slew,
        "rejected_command_intervals_s": rejected,
        "faults": faults,
        "tracking_windows_s": tracking,
        "outlier_frames_detected": int(t_out.size),
        "outlier_threshold_m": thr,
        "tracking_bound_m": TRACKING_BOUND_M,
        "estimation_bound_m": ESTIMATION_BOUND_M,
        "tracking_within_bound": bool(metrics["tracking_error_max_m"] <= TRACKING_BOUND_M),
    })

    net = _run_network(run)
    tree = load_network(net[0]) if net is not None else None
    p3 = positions_3d(ts) if tree is not None and tree.is_3d else None
    if net is not None:
        # the meshed wall, read from the run's own field (no solve for another blood model); a 3-D tree's in 3-D
        metrics.update(navigation_outcome(net[0], net[1], t, m["p_true"] if p3 is None else p3["p_true"],
                                          blood=_run_blood(run), pulsation=_run_pulsation(run)))
    # the slew limit in force as the coil recorded it (the dB/dt limit may have lowered it), else the config's
    recorded = np.asarray(ts.get("coil.slew_rate", np.zeros(0)))
    slew_limit = float(np.max(recorded)) if recorded.size else _slew_limit(run)
    figures = {
        FIGURES[0]: (fig9a_trajectory(t, m) if net is None
                     else tree_trajectory(t, p3, net[0], metrics) if p3 is not None
                     else network_trajectory(t, m, net[0], metrics)),
        FIGURES[1]: fig9b_errors(t, m, spans, after_s),
        FIGURES[2]: fig10a_gradients(t, m, spans, slew_limit),
        FIGURES[3]: fig10b_velocities(t, m, spans),
        FIGURES[4]: fig10c_velocity_error(t, m, spans),
        FIGURES[5]: forces_figure(t, m, spans),
    }
    frame_fig = mr_frame_figure(info, run, ts)
    if frame_fig is not None:
        figures[MR_FRAME_FIGURE] = frame_fig
    # each file whole or not at all: a full disk leaves the earlier report's files, never a 0-byte one
    try:
        for name, fig in figures.items():
            save_figure(fig, out / name, dpi=120)
    finally:
        for fig in figures.values():
            plt.close(fig)

    write_text(out / "metrics.json", json.dumps(_jsonable(metrics), indent=2, sort_keys=True) + "\n")
    return metrics


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x
