"""The Gymnasium environments against the compiled loop they step, side by side in one run (prints, asserts nothing).

Usage: .venv/bin/python bench/bench_env.py [--config sound_small_artery] [--copies 256] [--seconds 3]

Prints, on the scenario of ``vesselbot/Straight-v0`` by default (``sound_small_artery``, 2000 ticks at 1 kHz):

1. the compiled loop (:func:`vesselbot_ros.sim.compiled_loop.run_kernel`, the controller in the loop): ticks per
   second of CPU time, on one thread, and of wall time with ``run_many`` on 2 threads;
2. the scalar environment (``VesselbotEnv.step``, resets included): steps per second of CPU time, the actions the
   controller commanded in a run of the same seed (so the robot flies the same kind of path as in 1);
3. the vector environment of ``--copies`` copies (``VesselbotVectorEnv.step``, one compiled call per step): copy
   steps per second, on 1 thread (CPU time) and on 2 threads (wall time), every copy the same commands at its ticks
   (through the autoresets: an episode's command k at its tick k);

and the issue-43 targets: scalar >= 50,000 steps/s; vector >= 0.8x the compiled loop's ticks/s on the same 2 cores;
overhead (the environment's step time over the loop's tick time) <= 2x scalar, <= 1.2x vector.  Other jobs on the
machine stretch the wall figures: read them with the load average printed.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from vesselbot_ros.envs.env import VesselbotEnv
from vesselbot_ros.envs.vector import VesselbotVectorEnv
from vesselbot_ros.sim import compiled_loop
from vesselbot_ros.sim.closed_loop import prepared, run_closed_loop, run_many
from vesselbot_ros.sim.scenario import load_scenario


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} cores"


def loop_rate(sc, seconds: float) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Compiled-loop ticks per CPU second (one thread) and per wall second on 2 threads (run_many)."""
    inp = prepared(sc)
    compiled_loop.run_kernel(inp, np.random.default_rng(0))
    runs, t0 = 0, time.thread_time()
    while time.thread_time() - t0 < seconds:
        compiled_loop.run_kernel(inp, np.random.default_rng(runs))
        runs += 1
    one = runs * inp.n / (time.thread_time() - t0)
    batch = max(8, int(2 * one * seconds / inp.n))
    run_many(sc, range(2), workers=2)
    w0 = time.perf_counter()
    run_many(sc, range(batch), workers=2)
    two = batch * inp.n / (time.perf_counter() - w0)
    return one, two


#: Steps between looks at the clock: the thread's CPU clock is a system call (about a microsecond, a third of a
#: step), which a training loop does not make; the compiled loop's figure looks once per run of 2000 ticks.
CLOCK_EVERY = 500


def scalar_rate(sc, actions: np.ndarray, seconds: float) -> float:  # type: ignore[no-untyped-def]
    env = VesselbotEnv(sc)
    env.reset(seed=0)
    steps, k, t0 = 0, 0, time.thread_time()
    while time.thread_time() - t0 < seconds:
        for _ in range(CLOCK_EVERY):
            _o, _r, term, trunc, _i = env.step(actions[k])
            k += 1
            if term or trunc:
                env.reset()
                k = 0
        steps += CLOCK_EVERY
    return steps / (time.thread_time() - t0)


def vector_rate(sc, actions: np.ndarray, copies: int, threads: int, seconds: float) -> float:  # type: ignore[no-untyped-def]
    env = VesselbotVectorEnv(copies, sc, threads=threads)
    env.reset(seed=0)
    ticks, last = env.loop.ticks, len(actions) - 1
    clock = time.thread_time if threads == 1 else time.perf_counter
    calls, t0 = 0, clock()
    while clock() - t0 < seconds:
        env.step(actions[np.minimum(ticks, last)])  # each copy the command of its own tick (not one tick late after
        calls += 1                                  # an autoreset: a path into the wall costs many more plant steps)
    env.close()
    return calls * copies / (clock() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="sound_small_artery")
    ap.add_argument("--copies", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=3.0, help="timing per figure")
    args = ap.parse_args()
    sc = load_scenario(args.config)
    print(f"before: {_load()}")
    actions = run_closed_loop(sc, 0).timeseries["g_cmd"]  # the controller's commands: a realistic path
    loop1, loop2 = loop_rate(sc, args.seconds)
    scalar = scalar_rate(sc, actions, args.seconds)
    vec1 = vector_rate(sc, actions, args.copies, 1, args.seconds)
    vec2 = vector_rate(sc, actions, args.copies, 2, args.seconds)
    print(f"{sc.name}, {sc.sim.n_ticks} ticks per episode:")
    print(f"1. compiled loop:          {loop1:10,.0f} ticks/s (1 thread, CPU)   {loop2:10,.0f} ticks/s (2 threads, wall)")
    print(f"2. scalar env:             {scalar:10,.0f} steps/s (1 thread, CPU)   target >= 50,000: "
          f"{'met' if scalar >= 50_000 else 'MISSED'}; overhead {loop1 / scalar:.2f}x the loop's tick "
          f"(target <= 2x: {'met' if loop1 / scalar <= 2 else 'MISSED'})")
    print(f"3. vector env, {args.copies} copies: {vec1:10,.0f} steps/s (1 thread, CPU)   {vec2:10,.0f} steps/s (2 threads, "
          f"wall) = {vec2 / loop2:.2f}x the loop on 2 threads (target >= 0.8x: {'met' if vec2 / loop2 >= 0.8 else 'MISSED'}); "
          f"overhead {loop1 / vec1:.2f}x the loop's tick on 1 thread (target <= 1.2x: "
          f"{'met' if loop1 / vec1 <= 1.2 else 'MISSED'})")
    print(f"after:  {_load()}")


if __name__ == "__main__":
    main()
