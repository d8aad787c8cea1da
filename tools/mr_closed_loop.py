"""The closed loop flown from MR images: Folio 2017 and the clinical 3 T plan, seeds 0-4, typed noise against images.

Usage: ``python tools/mr_closed_loop.py [--write]`` (``--write`` puts the table into docs/imaging.md between
``<!-- BEGIN mr_closed_loop -->`` and ``<!-- END mr_closed_loop -->``).  A few minutes on one core.

Each scenario is flown as planned (``vesselbot plan``'s reference and flying options; the clinical plan is
shipped planned) twice over seeds 0-4: with the ``mri`` imager (the typed Gaussian noise, 100 um) and with the
``mr_images`` imager (MS-SET frames synthesised from the bead's field, one per tracking window, tracked by the
default tracker), the field of view centred on the path.  Per row: how many seeds end at the path's end (the
bead's centre within one bead diameter of the last reference point at the run's end), the worst time the bead's
centre spent outside the lumen (``|z| > D(t)/2``, eq. (13)), the tracking error after 0.6 s (max and rms, mean /
worst over seeds), the measurement error the observer got (each delivered frame against the bead's true position
at its acquisition time, along x and z: bias and rms over all frames of the five seeds) and the frames rejected.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from doc_sections import replace_section  # noqa: E402

from vesselbot_ros.analysis.plan import flying_changes, make_plan, plan_scenario  # noqa: E402
from vesselbot_ros.atomic_io import write_text  # noqa: E402
from vesselbot_ros.physics.blood_flow import vessel_diameter  # noqa: E402
from vesselbot_ros.sim.closed_loop import run_closed_loop  # noqa: E402
from vesselbot_ros.sim.scenario import Scenario, load_scenario, scenario_from_mapping, scenario_with  # noqa: E402

DOC = ROOT / "docs" / "imaging.md"
SEEDS = range(5)
#: (label, scenario, plan it first)
SCENARIOS = (("Folio & Ferreira 2017 (`folio_2017_tro`, planned)", "folio_2017_tro", True),
             ("clinical 3 T plan (`config/plans/clinical_3t.yaml`)", "config/plans/clinical_3t.yaml", False))


def flown(name: str, plan_first: bool) -> Scenario:
    base = load_scenario(name)
    if not plan_first:
        return base
    plan = make_plan(base)
    planned = plan_scenario(base, plan.reference)
    return scenario_with(planned, flying_changes(planned, plan))


def with_images(sc: Scenario) -> Scenario:
    """``sc`` with the MR imager (MS-SET, the default preset), its field of view centred on the path."""
    ref = sc.reference
    xs = np.asarray(ref.anchors_x_m, dtype=np.float64)
    centre = [float(0.5 * (xs.min() + xs.max())), 0.0, 0.0]
    m = sc.to_mapping()
    m["imager"] = {"kind": "mr_images", "fov_centre_m": centre}
    return scenario_from_mapping(m)


def fly(sc: Scenario) -> dict:
    phys = sc.physics
    flow = phys.flow
    radius = phys.robot.radius_m
    reached, outside, mx, rms, errs, rejected, frames = 0, [], [], [], [], 0, 0
    for seed in SEEDS:
        r = run_closed_loop(sc, seed)
        ts, m = r.timeseries, r.metrics
        assert m["status"] == "ok", (sc.name, seed, m["status"])
        p, t = ts["p_true"], ts["t_s"]
        reached += int(np.linalg.norm(p[-1] - ts["p_ref"][-1]) <= 2.0 * radius)
        d_t = np.array([vessel_diameter(float(tk), phys.vessel.diameter_m, flow.diameter_pulsation,
                                        flow.angular_frequency_rad_per_s, flow.phase_rad) for tk in t])
        outside.append(float(np.count_nonzero(np.abs(p[:, -1]) > 0.5 * d_t)) * sc.sim.dt_control_s)
        mx.append(m["tracking_error_max_m"])
        rms.append(m["tracking_error_rms_m"])
        k = np.flatnonzero(np.isfinite(ts["meas_p"][:, 0]))
        fresh = k[np.r_[True, np.diff(ts["meas_t_acq_s"][k]) > 0]] if k.size else k
        at = np.clip(np.searchsorted(t, ts["meas_t_acq_s"][fresh] - 1e-9), 0, len(t) - 1)
        errs.append(ts["meas_p"][fresh] - p[at])
        rejected += int(m.get("imager_frames_rejected", 0))
        frames += int(m.get("imager_frames", len(fresh)))
    e = np.concatenate(errs)
    return {"reached": reached, "outside_worst_s": max(outside), "max_mean": float(np.mean(mx)),
            "max_worst": float(np.max(mx)), "rms_mean": float(np.mean(rms)), "rms_worst": float(np.max(rms)),
            "bias": e.mean(axis=0), "err_rms": np.sqrt((e ** 2).mean(axis=0)), "n_frames": len(e),
            "rejected": rejected, "frames": frames}


def table() -> str:
    um = 1e6
    lines = ["| scenario | imager | reach the path's end | outside the lumen, worst (s) | tracking max after 0.6 s, "
             "mean / worst (µm) | tracking rms, mean / worst (µm) | measurement error x, z: bias / rms (µm) | "
             "frames (rejected) |", "|---|---|---|---|---|---|---|---|"]
    for label, name, plan_first in SCENARIOS:
        sc = flown(name, plan_first)
        for imager, s in (("`mri`: typed noise, " + f"{sc.imager.noise_sigma_m * um:.0f} µm", sc),
                          ("`mr_images`: MS-SET frames, tracked", with_images(sc))):
            t0 = time.perf_counter()
            r = fly(s)
            print(f"{name} {imager}: {time.perf_counter() - t0:.1f} s", flush=True)
            err = ", ".join(f"{b * um:+.0f} / {q * um:.0f}" for b, q in zip(r["bias"], r["err_rms"], strict=True))
            lines.append(f"| {label} | {imager} | {r['reached']}/{len(SEEDS)} | {r['outside_worst_s']:.3f} | "
                         f"{r['max_mean'] * um:.1f} / {r['max_worst'] * um:.1f} | "
                         f"{r['rms_mean'] * um:.1f} / {r['rms_worst'] * um:.1f} | {err} | "
                         f"{r['n_frames']} ({r['rejected']}) |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--write", action="store_true", help="write the table into docs/imaging.md")
    args = ap.parse_args()
    text = table()
    print(text)
    if args.write:
        write_text(DOC, replace_section(DOC.read_text(), "mr_closed_loop", text, "docs/imaging.md"))
        print(f"wrote {DOC.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
