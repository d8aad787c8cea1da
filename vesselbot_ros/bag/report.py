"""Figures and metrics of a run computed from its bag alone (paper Figs. 9 and 10).

:func:`write_report` reads a bag (:func:`~vesselbot_ros.bag.reader.read_timeseries`),
aligns the per-tick topics on their stamps, computes the metrics with the
*same* function as the ROS-free runner
(:func:`vesselbot_ros.sim.metrics.compute_metrics`) and writes, into
``<bag>/report/`` by default:

* ``fig9a_trajectory.png``: XZ trajectory, reference, estimate, vessel walls;
* ``fig9b_errors.png``: tracking and estimation error (log scale) with the
  paper's 150 um and 10 um lines;
* ``fig10a_gradients.png``: commanded vs applied gradients, +/- saturation;
* ``fig10b_velocities.png``: true and estimated velocities;
* ``fig10c_velocity_error.png``: velocity estimation error;
* ``forces.png``: the force breakdown of eq. (1) over time;
* ``metrics.json``: the metrics plus bag facts (scenario, seed, counts,
  intervals of saturation, slew limiting and faults).

Every time plot shades saturated (red), slew-limited (orange) and fault
(grey) intervals.  Faults are the imager's scheduled outlier bursts and
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
from vesselbot_ros.bag.reader import BagInfo, open_bag, read_timeseries
from vesselbot_ros.errors import BagError

__all__ = ["write_report", "metrics_timeseries", "bool_intervals", "detect_outlier_frames", "diagnostic_counters",
           "DIAGNOSTIC_COUNTERS", "FIGURES"]

TRACKING_BOUND_M = 150e-6  # paper Fig. 9b: tracking error bound after 0.6 s
ESTIMATION_BOUND_M = 10e-6  # paper Fig. 9b: estimation error bound
FIGURES = ("fig9a_trajectory.png", "fig9b_errors.png", "fig10a_gradients.png", "fig10b_velocities.png",
           "fig10c_velocity_error.png", "forces.png")
_XZ = [0, 2]


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


def metrics_timeseries(ts: Mapping[str, np.ndarray], dt_s: float | None = None) -> dict[str, np.ndarray]:
    """The per-tick series :func:`vesselbot_ros.sim.metrics.compute_metrics` takes, from bag arrays.

    Ticks are the stamps present on ``truth``, ``reference``, ``estimate`` and
    ``coil`` state; vectors keep (x, z).

    Args:
        ts: Arrays from :func:`~vesselbot_ros.bag.reader.read_timeseries`.
        dt_s: Control period (s).  Given, tick times are rebuilt as ``k * dt_s``
            with ``k`` recovered from the stamp (the graph's convention, so the
            metrics equal the launcher's bit for bit); None: ``stamp * 1e-9``.

    Raises:
        BagError: if one of those topics is missing or empty.
    """
    idx = _align(ts, ("truth", "reference", "estimate", "coil"))
    tr, rf, es, co = idx["truth"], idx["reference"], idx["estimate"], idx["coil"]
    if dt_s is not None:
        t_s = np.round(idx["_ns"] * 1e-9 / dt_s).astype(np.int64) * dt_s
    else:
        t_s = idx["_ns"].astype(np.float64) * 1e-9
    return {
        "t_s": t_s,
        "p_true": ts["truth.p_WR"][tr][:, _XZ],
        "v_true": ts["truth.v_WR"][tr][:, _XZ],
        "p_ref": ts["reference.p_ref"][rf][:, _XZ],
        "x_hat": ts["estimate.p_hat"][es][:, _XZ],
        "z_hat": ts["estimate.v_hat"][es][:, _XZ],
        "g_applied": ts["coil.applied"][co][:, _XZ],
        "g_cmd": ts["coil.commanded"][co][:, _XZ],
        "saturated": ts["coil.saturated"][co].astype(bool),
        "slew_limited": np.stack([ts["coil.slew_limited_x"][co], ts["coil.slew_limited_z"][co]], axis=1).astype(bool),
        "in_contact": ts["truth.in_contact"][tr].astype(bool),
        "diameter_m": ts["truth.diameter_m"][tr],
        "max_gradient": ts["coil.max_gradient"][co],
        "forces": np.stack([ts[f"truth.F_{k}"][tr][:, _XZ] for k in
                            ("magnetic", "drag", "apparent_weight", "contact", "van_der_waals", "electrostatic",
                             "steric", "total")], axis=1),
    }


def detect_outlier_frames(ts: Mapping[str, np.ndarray]) -> tuple[npt.NDArray[np.float64], float]:
    """Acquisition times (s) of fresh measurements far from the truth, and the threshold used (m).

    The distance is ``|p_meas - p_true(t_acq)|`` in the xz plane, the truth
    interpolated at the acquisition stamp; the threshold is
    ``max(10 um, median + 10 * MAD)`` over all fresh frames.
    """
    if "measurement.t_s" not in ts or "truth.t_s" not in ts or len(ts["measurement.t_s"]) == 0:
        return np.zeros(0), float("nan")
    fresh = ts["measurement.fresh"].astype(bool)
    t_m = ts["measurement.t_s"][fresh]
    p_m = ts["measurement.p_meas"][fresh][:, _XZ]
    t_tr = ts["truth.t_s"]
    order = np.argsort(t_tr, kind="stable")
    p_tr = np.stack([np.interp(t_m, t_tr[order], ts["truth.p_WR"][order][:, a]) for a in _XZ], axis=1)
    d = np.linalg.norm(p_m - p_tr, axis=1)
    if d.size == 0:
        return np.zeros(0), float("nan")
    med = float(np.median(d))
    mad = float(np.median(np.abs(d - med)))
    thr = max(10e-6, med + 10.0 * mad)
    return t_m[d > thr], thr


def _fault_intervals(ts: Mapping[str, np.ndarray], run: Mapping[str, Any], dt: float) -> list[dict[str, Any]]:
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
    t_out, _thr = detect_outlier_frames(ts)
    for a, b in bool_intervals(t_out, np.ones(t_out.size, bool)) if t_out.size > 1 else [
            (float(t), float(t) + dt) for t in t_out]:
        out.append({"kind": "outlier_frames", "source": "detected", "start_s": a, "end_s": max(b, a + dt)})
    return out


def _shade(ax: Any, spans: Mapping[str, list[tuple[float, float]]]) -> None:
    colors = {"saturated": ("tab:red", 0.15), "slew limited": ("tab:orange", 0.12), "fault": ("0.5", 0.25)}
    for label, ivs in spans.items():
        color, alpha = colors[label]
        for i, (a, b) in enumerate(ivs):
            ax.axvspan(a, b, color=color, alpha=alpha, lw=0, label=label if i == 0 else None)


#: Counters the launcher adds to the run's metrics from the nodes' final ``/diagnostics``
#: (node role -> keys); the plant's are ``plant_node.PLANT_STAT_NAMES`` (tested equal).
DIAGNOSTIC_COUNTERS: dict[str, tuple[str, ...]] = graph_spec.diagnostic_counters()


def _run_config_value(run: Mapping[str, Any], section: str, key: str) -> float | None:
    try:
        v = float(run["config"][section][key])
    except (KeyError, TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def diagnostic_counters(info: BagInfo) -> dict[str, int]:
    """The launcher's extra metrics (plant/observer/imager counters) from the bag's final diagnostics."""
    from vesselbot_ros.bag.reader import final_diagnostics
    from vesselbot_ros.graph_spec import NODE_NAMES

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


def write_report(bag_dir: str | Path | BagInfo, out_dir: str | Path | None = None,
                 after_s: float | None = None) -> dict[str, Any]:
    """Write the figures and ``metrics.json`` of a recorded run; return the metrics.

    The metrics are those of ``vesselbot run`` for the same run: the same
    :func:`~vesselbot_ros.sim.metrics.compute_metrics` on the same per-tick
    values (tick times ``k * dt`` with dt from the run's config), plus the
    plant, observer and imager counters from the nodes' final diagnostics.

    Args:
        bag_dir: The bag directory (or a validated :class:`BagInfo`).
        out_dir: Output folder (default ``<bag_dir>/report``).
        after_s: Start of the steady-state window of the metrics (s); None:
            the run's ``sim.metrics_after_s``, else 0.6 (paper).

    Raises:
        BagError: if the bag is invalid, corrupt or lacks the graph's topics.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vesselbot_ros.sim.metrics import compute_metrics

    info = bag_dir if isinstance(bag_dir, BagInfo) else open_bag(bag_dir)
    out = Path(out_dir) if out_dir is not None else info.path / "report"
    out.mkdir(parents=True, exist_ok=True)
    run = info.run_metadata
    rate = _run_config_value(run, "sim", "control_rate_Hz")
    if after_s is None:
        after_s = _run_config_value(run, "sim", "metrics_after_s")
        after_s = 0.6 if after_s is None else after_s
    ts = read_timeseries(info)
    m = metrics_timeseries(ts, dt_s=1.0 / rate if rate else None)
    t = m["t_s"]
    if t.size < 2:
        raise BagError(f"bag {info.path} holds {t.size} complete tick(s); the report needs at least 2")
    dt = float(np.median(np.diff(t)))
    metrics: dict[str, Any] = dict(compute_metrics(m, after_s=after_s))
    sat = bool_intervals(t, m["saturated"])
    slew = bool_intervals(t, m["slew_limited"].any(axis=1))
    faults = _fault_intervals(ts, info.run_metadata, dt)
    spans = {"saturated": sat, "slew limited": slew, "fault": [(f["start_s"], f["end_s"]) for f in faults]}
    t_out, thr = detect_outlier_frames(ts)
    metrics.update(diagnostic_counters(info))
    metrics.update({
        "bag": str(info.path),
        "scenario": run.get("scenario"),
        "seed": run.get("seed"),
        "mode": run.get("mode"),
        "message_counts": {tp.name: tp.count for tp in info.topics},
        "saturated_intervals_s": sat,
        "slew_limited_intervals_s": slew,
        "faults": faults,
        "outlier_frames_detected": int(t_out.size),
        "outlier_threshold_m": thr,
        "tracking_bound_m": TRACKING_BOUND_M,
        "estimation_bound_m": ESTIMATION_BOUND_M,
        "tracking_within_bound": bool(metrics["tracking_error_max_m"] <= TRACKING_BOUND_M),
    })

    mm = 1e3
    # Fig. 9a: XZ trajectory with the walls
    fig, ax = plt.subplots(figsize=(8, 4))
    x = m["p_true"][:, 0]
    order = np.argsort(x, kind="stable")
    ax.fill_between(x[order] * mm, m["diameter_m"][order] / 2 * mm, (m["diameter_m"].max() / 2 * 1.15) * mm,
                    color="0.85", label="vessel wall")
    ax.fill_between(x[order] * mm, -m["diameter_m"][order] / 2 * mm, -(m["diameter_m"].max() / 2 * 1.15) * mm,
                    color="0.85")
    ax.plot(m["p_ref"][:, 0] * mm, m["p_ref"][:, 1] * mm, "k--", lw=1.2, label="reference")
    ax.plot(m["p_true"][:, 0] * mm, m["p_true"][:, 1] * mm, "tab:blue", lw=1.2, label="robot (truth)")
    ax.plot(m["x_hat"][:, 0] * mm, m["x_hat"][:, 1] * mm, "tab:green", lw=0.8, alpha=0.8, label="estimate")
    ax.set(xlabel="x (mm)", ylabel="z (mm)", title="Fig. 9a: trajectory in the vessel (XZ)")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / FIGURES[0], dpi=120)
    plt.close(fig)

    # Fig. 9b: errors, log scale
    e_tr = np.linalg.norm(m["p_true"] - m["p_ref"], axis=1)
    e_es = np.linalg.norm(m["x_hat"] - m["p_true"], axis=1)
    fig, ax = plt.subplots(figsize=(8, 4))
    _shade(ax, spans)
    ax.semilogy(t, np.maximum(e_tr, 1e-12), "tab:blue", lw=1, label="tracking error |p - p_ref|")
    ax.semilogy(t, np.maximum(e_es, 1e-12), "tab:green", lw=1, label="estimation error |p_hat - p|")
    ax.axhline(TRACKING_BOUND_M, color="tab:blue", ls=":", label="150 um")
    ax.axhline(ESTIMATION_BOUND_M, color="tab:green", ls=":", label="10 um")
    ax.axvline(after_s, color="k", ls="--", lw=0.8)
    ax.set(xlabel="t (s)", ylabel="error (m)", title="Fig. 9b: tracking and estimation error")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / FIGURES[1], dpi=120)
    plt.close(fig)

    # Fig. 10a: gradients
    fig, axs = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
    for i, axis in enumerate("xz"):
        a = axs[i]
        _shade(a, spans)
        a.plot(t, m["g_cmd"][:, i] * mm, "tab:gray", lw=0.8, label="commanded")
        a.plot(t, m["g_applied"][:, i] * mm, "tab:red", lw=1.0, label="applied")
        a.plot(t, m["max_gradient"] * mm, "k:", lw=0.8, label="+/- U_sat")
        a.plot(t, -m["max_gradient"] * mm, "k:", lw=0.8)
        a.set_ylabel(f"U_{axis} (mT/m)")
    axs[0].set_title("Fig. 10a: commanded vs applied gradient")
    axs[0].legend(loc="best", fontsize=8)
    axs[1].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(out / FIGURES[2], dpi=120)
    plt.close(fig)

    # Fig. 10b: velocities
    fig, axs = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
    for i, axis in enumerate("xz"):
        a = axs[i]
        _shade(a, spans)
        a.plot(t, m["v_true"][:, i] * mm, "tab:blue", lw=1.0, label="true")
        a.plot(t, m["z_hat"][:, i] * mm, "tab:green", lw=0.8, label="estimated")
        a.set_ylabel(f"v_{axis} (mm/s)")
    axs[0].set_title("Fig. 10b: true and estimated velocity")
    axs[0].legend(loc="best", fontsize=8)
    axs[1].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(out / FIGURES[3], dpi=120)
    plt.close(fig)

    # Fig. 10c: velocity error
    fig, ax = plt.subplots(figsize=(8, 3.5))
    _shade(ax, spans)
    for i, axis in enumerate("xz"):
        ax.plot(t, (m["z_hat"][:, i] - m["v_true"][:, i]) * mm, lw=1.0, label=f"v_hat_{axis} - v_{axis}")
    ax.set(xlabel="t (s)", ylabel="mm/s", title="Fig. 10c: velocity estimation error")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / FIGURES[4], dpi=120)
    plt.close(fig)

    # Force breakdown
    names = ("magnetic", "drag", "apparent weight", "contact", "van der Waals", "electrostatic", "steric", "total")
    fig, ax = plt.subplots(figsize=(8, 4.5))
    _shade(ax, spans)
    for k, name in enumerate(names):
        f = np.linalg.norm(m["forces"][:, k, :], axis=1)
        if np.any(f > 0):
            ax.semilogy(t, np.where(f > 0, f, np.nan), lw=1.6 if name == "total" else 0.9,
                        ls="--" if name == "total" else "-", label=name)
    ax.set(xlabel="t (s)", ylabel="|F| (N)", title="Force breakdown, eq. (1)")
    ax.legend(loc="best", fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(out / FIGURES[5], dpi=120)
    plt.close(fig)

    (out / "metrics.json").write_text(json.dumps(_jsonable(metrics), indent=2, sort_keys=True) + "\n",
                                      encoding="utf-8")
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
