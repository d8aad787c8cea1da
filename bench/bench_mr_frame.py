#!/usr/bin/env python3
"""One MR frame's synthesis plus tracking, against the clinical sequence's frame period, measured in one run.

Frames: a 128 x 128 gradient-echo slice (preset ``gre_3t``) and three 256-sample MS-SET projections (preset
``msset_1p5t``), the paper's bead in the 3 mm vessel, a new bead position every frame (the FOV fixed, so the
tracker's background is computed once, as in use).  Prints the median and best wall time per frame of the
synthesis (``acquire_*``), of the tracking (``*Tracker.track``) and of both, beside the ``clinical_3t``
sequence's period (tracking + propulsion + dead times) and tracking window, as ratios (the issue's target:
synthesis plus tracking within one frame period on one core).  Also printed: the time the scanner itself needs to
acquire the frame (``MrImagingParams.frame_time_s``), which is what a real tracking window has to hold.

Usage: ``NUMBA_NUM_THREADS=1 python bench/bench_mr_frame.py [--frames 20]``
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from vesselbot_ros.imaging.acquisition import PRESETS, MrImagingParams, acquire_projections, acquire_slice
from vesselbot_ros.imaging.tracker import ProjectionTracker, SliceTracker
from vesselbot_ros.physics.params import RobotParams
from vesselbot_ros.scanner.hardware import PRESETS as HARDWARE

ROBOT = RobotParams()
VESSEL_M = 3e-3
CENTRE = np.zeros(3)


def _run(params: MrImagingParams, frames: int) -> tuple[list[float], list[float]]:
    rng = np.random.default_rng(0)
    slice_ = params.acquisition == "slice"
    tracker: SliceTracker | ProjectionTracker = (SliceTracker(params, ROBOT, VESSEL_M) if slice_
                                                 else ProjectionTracker(params, ROBOT, VESSEL_M))
    acquire: Callable[..., object] = acquire_slice if slice_ else acquire_projections
    synth, track = [], []
    for i in range(frames + 2):  # two warm-up frames: compilation, the tracker's cached background
        bead = np.array([1e-3 * np.sin(0.7 * i), 0.0 if slice_ else 0.3e-3 * np.cos(i), 0.4e-3 * np.cos(0.9 * i)])
        t0 = time.perf_counter()
        frame = acquire(params, ROBOT, bead, rng, CENTRE, VESSEL_M)
        t1 = time.perf_counter()
        res = tracker.track(frame)  # type: ignore[arg-type]
        t2 = time.perf_counter()
        if not res.accepted:
            raise SystemExit(f"frame {i} rejected: {res.reason}")
        if i >= 2:
            synth.append(t1 - t0)
            track.append(t2 - t1)
    return synth, track


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=20)
    args = ap.parse_args()
    seq = HARDWARE["clinical_3t"].sequence
    period, window = seq.period_s, seq.tracking_window_s
    print(f"clinical_3t: frame period {period * 1e3:.1f} ms (tracking window {window * 1e3:.1f} ms)\n")
    print("| frame | synthesis (ms) | tracking (ms) | both (ms) | both / period | both / window "
          "| scanner's acquisition (ms) | acquisition / window |")
    print("|---|---|---|---|---|---|---|---|")
    for label, params in (("slice 128 x 128 (gre_3t)", PRESETS["gre_3t"]),
                          ("3 projections x 256 (msset_1p5t)", PRESETS["msset_1p5t"])):
        synth, track = _run(params, args.frames)
        both = [a + b for a, b in zip(synth, track, strict=True)]
        med = statistics.median
        print(f"| {label} | {med(synth) * 1e3:.1f} (best {min(synth) * 1e3:.1f}) | {med(track) * 1e3:.1f} "
              f"(best {min(track) * 1e3:.1f}) | {med(both) * 1e3:.1f} | {med(both) / period:.2f} | "
              f"{med(both) / window:.2f} | {params.frame_time_s * 1e3:.0f} | {params.frame_time_s / window:.1f} |")


if __name__ == "__main__":
    main()
