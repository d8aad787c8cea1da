"""Tests of the campaign's unit of work: content addresses and run_chunk."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.campaign.runner import (
    RunTask,
    SeedHasher,
    code_version,
    flatten_timeseries,
    resolve_mapping,
    run_chunk,
    run_id,
)
from vesselbot_ros.config import load_yaml
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import scenario_from_mapping

ROOT = Path(__file__).resolve().parents[3]


def _mapping(seed: int = 0, duration: float = 0.05) -> dict:
    m = load_yaml(ROOT / "config" / "sound_small_artery.yaml")
    m["sim"]["duration_s"] = duration
    m["sim"]["metrics_after_s"] = 0.0
    m["seed"] = seed
    return m


def _task(index: int, mapping: dict, keep: bool = False) -> RunTask:
    return RunTask(index, run_id(mapping, code_version()), mapping["seed"], mapping, keep)


def test_run_id_is_a_content_address() -> None:
    code = code_version()
    assert len(code) == 16 and int(code, 16) >= 0
    assert code_version() == code
    a = resolve_mapping(_mapping(0))
    assert run_id(a, code) == run_id(copy.deepcopy(a), code)
    assert run_id(a, code) != run_id(resolve_mapping(_mapping(1)), code)  # seed
    assert run_id(a, code) != run_id(a, "0" * 16)  # code version
    b = copy.deepcopy(a)
    b["imager"]["noise_sigma_m"] *= 1.0 + 1e-15
    assert run_id(a, code) != run_id(b, code)  # any value, to the last bit
    # a spelled-out default and an omitted one resolve to the same run
    sparse = _mapping(0)
    full = _mapping(0)
    full["sim"]["record_forces"] = False
    assert run_id(resolve_mapping(sparse), code) == run_id(resolve_mapping(full), code)


def test_run_chunk_reproduces_run_closed_loop_bit_for_bit() -> None:
    tasks = [_task(0, resolve_mapping(_mapping(3)), keep=True), _task(1, resolve_mapping(_mapping(4)))]
    recs = run_chunk(tasks, code_version())
    assert [r["run_id"] for r in recs] == [t.run_id for t in tasks]
    assert all(r["status"] == "ok" and r["error"] is None and r["run_time_s"] > 0 for r in recs)
    direct = run_closed_loop(scenario_from_mapping(_mapping(3)))
    for k, v in direct.metrics.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            assert recs[0]["metrics"][k] == v or (np.isnan(v) and np.isnan(recs[0]["metrics"][k])), k
    ts = recs[0]["timeseries"]
    np.testing.assert_array_equal(ts["p_true_x"], direct.timeseries["p_true"][:, 0])
    np.testing.assert_array_equal(ts["g_applied_z"], direct.timeseries["g_applied"][:, 1])
    assert recs[1]["timeseries"] is None
    assert recs[0]["metrics"]["seed"] == 3 and recs[1]["metrics"]["seed"] == 4


def test_a_failing_run_is_recorded_and_the_chunk_goes_on(monkeypatch) -> None:
    bad = _mapping(1)
    bad["physics"]["robot"]["radius_m"] = -1e-4  # invalid: raises while the run is built
    tasks = [_task(0, _mapping(0)), _task(1, bad), _task(2, _mapping(2)), _task(3, _mapping(3))]
    import vesselbot_ros.sim.closed_loop as cl  # run_chunk looks it up there at call time

    orig = cl.run_closed_loop

    def flaky(scenario, seed=None):
        if scenario.seed == 2:
            raise RuntimeError("integrator exploded at tick 17")
        return orig(scenario, seed)

    monkeypatch.setattr(cl, "run_closed_loop", flaky)
    recs = run_chunk(tasks, code_version())
    assert [r["status"] for r in recs] == ["ok", "error", "error", "ok"]
    assert recs[1]["error"] == "ConfigError: physics.robot.radius_m must be > 0, got -0.0001"
    assert recs[2]["error"] == "RuntimeError: integrator exploded at tick 17"
    assert recs[1]["metrics"] == {} and recs[3]["metrics"]["seed"] == 3


def test_with_a_budget_runs_run_in_a_process_of_their_own_and_a_crash_there_is_one_failed_run(monkeypatch) -> None:
    """With a budget, a run that kills its process (compiled code crashing) fails alone; the others give
    the numbers of the worker thread itself, keep_timeseries included."""
    import concurrent.futures
    import os

    import vesselbot_ros.sim.closed_loop as cl

    tasks = [_task(0, resolve_mapping(_mapping(0)), keep=True), _task(1, _mapping(1)), _task(2, _mapping(2))]
    here = run_chunk(tasks, code_version())  # also loads the compiled loop that the run processes inherit
    orig = cl.run_closed_loop

    def crash_at_seed_1(scenario, seed=None):
        if seed == 1:
            os._exit(7)
        return orig(scenario, seed)

    monkeypatch.setattr(cl, "run_closed_loop", crash_at_seed_1)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:  # a fresh thread: its run process is forked after the patch
        recs = pool.submit(run_chunk, tasks, code_version(), 60.0).result()
    assert [r["status"] for r in recs] == ["ok", "error", "ok"]
    assert recs[1]["error"] == "RunProcessDied: the run's process ended (exit code 7) before returning the run"
    for a, b in ((here[0], recs[0]), (here[2], recs[2])):
        assert a["metrics"].keys() == b["metrics"].keys()
        assert all(a["metrics"][k] == b["metrics"][k] or np.isnan(a["metrics"][k]) for k in a["metrics"])
    np.testing.assert_array_equal(recs[0]["timeseries"]["p_true_x"], here[0]["timeseries"]["p_true_x"])
    assert recs[0]["worker"] == here[0]["worker"] == f"{__import__('socket').gethostname()}:{os.getpid()}"
    with pytest.raises(ValueError, match="run_timeout_s must be > 0 s, got 0.0"):
        run_chunk(tasks, code_version(), 0.0)


def test_a_run_process_kept_across_chunks_ends_idle_and_the_next_chunk_forks_a_new_one(monkeypatch) -> None:
    import concurrent.futures

    import vesselbot_ros.campaign.runner as runner

    monkeypatch.setattr(runner, "IDLE_EXIT_S", 5.0)  # "at once" below is well within it, even on a loaded machine
    tasks = [_task(0, _mapping(0)), _task(1, _mapping(1))]
    here = run_chunk(tasks, code_version())  # this process loads the compiled loop; the run processes inherit it
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        first = pool.submit(run_chunk, tasks[:1], code_version(), 60.0).result()
        pid = pool.submit(lambda: runner._THREAD.proc.pid).result()
        kept = pool.submit(run_chunk, tasks[1:], code_version(), 60.0).result()  # at once: the same process
        assert pool.submit(lambda: runner._THREAD.proc.pid).result() == pid
        # the process ends idle (its end of the pipe closes: EOF), bounded; the chunk sent to it then finds it gone
        # and runs in a new one
        assert pool.submit(lambda: runner._THREAD.proc.conn.poll(120.0)).result()
        again = pool.submit(run_chunk, tasks, code_version(), 60.0).result()
        assert pool.submit(lambda: runner._THREAD.proc.pid).result() != pid
    assert [r["status"] for r in first + kept + again] == ["ok"] * 4
    assert [r["metrics"] for r in first + kept] == [r["metrics"] for r in here] == [r["metrics"] for r in again]


def test_a_worker_with_other_code_refuses_to_run() -> None:
    recs = run_chunk([_task(0, _mapping(0))], "ffffffffffffffff")
    assert recs[0]["status"] == "error"
    assert recs[0]["error"].startswith(f"VersionMismatch: worker code version {code_version()} differs")


def test_flatten_timeseries_splits_vectors() -> None:
    n = 4
    flat = flatten_timeseries({"t_s": np.arange(n), "p": np.ones((n, 2)), "f": np.zeros((n, 8, 2)),
                               "b": np.zeros((n, 2), dtype=bool)})
    assert set(flat) == {"t_s", "p_x", "p_z", "b_x", "b_z"} | {f"f_{i}_{a}" for i in range(8) for a in "xz"}
    assert all(v.shape == (n,) for v in flat.values())
    assert flat["b_x"].dtype == bool
    flat3 = flatten_timeseries({"p": np.arange(3 * n).reshape(n, 3), "f": np.zeros((n, 8, 3))})  # a 3-D tree's
    assert set(flat3) == {"p_x", "p_y", "p_z"} | {f"f_{i}_{a}" for i in range(8) for a in "xyz"}
    assert list(flat3["p_y"]) == [1, 4, 7, 10]


@pytest.mark.parametrize("seed", [0, 7])
def test_resolve_mapping_round_trips(seed) -> None:
    m = resolve_mapping(_mapping(seed))
    assert resolve_mapping(m) == m and m["seed"] == seed


@pytest.mark.parametrize("seed", [0, 7, 12345, 2**40])
def test_seed_hasher_gives_run_id_of_every_seed(seed) -> None:
    code = code_version()
    m = resolve_mapping(_mapping(0))
    h = SeedHasher(m, code)
    assert h(seed) == run_id({**m, "seed": seed}, code)
    assert h(seed) != h(seed + 1)
    assert len(h.key) == 24 and h.key == SeedHasher({**m, "seed": seed}, code).key  # the key ignores the seed
    assert h.key != SeedHasher(m, "0" * 16).key  # ... but not the code
    other = copy.deepcopy(m)
    other["imager"]["noise_sigma_m"] *= 2.0
    assert SeedHasher(other, code).key != h.key


def test_runs_of_one_shared_scenario_build_it_once_and_match_run_closed_loop(monkeypatch) -> None:
    import vesselbot_ros.campaign.runner as runner
    import vesselbot_ros.sim.scenario as scenario_mod

    shared = resolve_mapping(_mapping(0))
    hasher = SeedHasher(shared, code_version())
    tasks = [RunTask(i, hasher(s), s, shared, False, hasher.key) for i, s in enumerate([5, 6, 7])]
    built = []
    orig = scenario_mod.scenario_from_mapping
    monkeypatch.setattr(scenario_mod, "scenario_from_mapping", lambda m: built.append(1) or orig(m))
    monkeypatch.setattr(runner, "_SCENARIOS", type(runner._SCENARIOS)())
    recs = run_chunk(tasks, code_version()) + run_chunk(tasks[:1], code_version())  # a second chunk: kept built
    assert len(built) == 1
    for rec, seed in zip(recs, [5, 6, 7, 5]):
        direct = run_closed_loop(scenario_from_mapping(_mapping(seed)))
        assert rec["status"] == "ok" and rec["metrics"]["seed"] == seed
        for k, v in direct.metrics.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                assert rec["metrics"][k] == v or (np.isnan(v) and np.isnan(rec["metrics"][k])), k


def test_an_invalid_shared_scenario_fails_each_of_its_runs() -> None:
    bad = _mapping(0)
    bad["physics"]["robot"]["radius_m"] = -1e-4
    tasks = [RunTask(i, f"r{i}", s, bad, False) for i, s in enumerate([1, 2])]
    recs = run_chunk(tasks, code_version())
    assert [r["status"] for r in recs] == ["error", "error"]
    assert all(r["error"] == "ConfigError: physics.robot.radius_m must be > 0, got -0.0001" for r in recs)


def test_run_ids_of_a_users_kind_follow_its_source(tmp_path, monkeypatch) -> None:
    """Editing a plug-in gives its runs new addresses (a resumed campaign reruns them); built-in runs keep theirs."""
    from vesselbot_ros.campaign.runner import resolve_with_code

    src = (Path(__file__).resolve().parents[3] / "test" / "plugins" / "vesselbot_test_plugin.py").read_text()
    (tmp_path / "ids_plugin.py").write_text(src)
    monkeypatch.syspath_prepend(str(tmp_path))
    m = _mapping(0)
    assert resolve_with_code(m, "c0") == (resolve_mapping(m), "c0")
    m["controller"] = {"kind": "ids_plugin:IntegralController"}
    resolved, code = resolve_with_code(m, "c0")
    assert code.startswith("c0+") and resolved["controller"]["kind"] == "ids_plugin:IntegralController"
    (tmp_path / "ids_plugin.py").write_text(src + "\n# edited\n")
    assert resolve_with_code(m, "c0")[1] != code


def test_a_run_on_rejected_commands_is_not_ok_and_says_why(monkeypatch) -> None:
    """A controller that sends NaN from 0.1 s (issue 38): the run completes but its status is rejected_commands,
    its error column the one warning line, and its metrics count the rejected ticks; a sound run stays ok."""
    monkeypatch.syspath_prepend(str(ROOT / "test" / "plugins"))
    bad = _mapping(0, duration=0.2)
    bad["controller"] = {"kind": "vesselbot_hostile_plugin:NaNFrom", "start_s": 0.1}
    recs = run_chunk([_task(0, resolve_mapping(bad)), _task(1, resolve_mapping(_mapping(0, duration=0.2)))],
                     code_version())
    assert recs[0]["status"] == "rejected_commands"
    assert recs[0]["error"] == ("100 of 200 controller commands rejected (non-finite) from t = 0.100 s; "
                                "the coil ramped to zero")
    assert recs[0]["metrics"]["rejected_commands"] == 100
    assert recs[0]["metrics"]["first_rejected_command_s"] == pytest.approx(0.1, abs=1e-12)
    assert recs[1]["status"] == "ok" and recs[1]["error"] is None and recs[1]["metrics"]["rejected_commands"] == 0
