"""Progress bars of the long steps (vesselbot_ros.progress): when they are drawn, what they say, and that a real
build's callback reaches its total."""

from __future__ import annotations

import argparse
import io
import types

import pytest

from vesselbot_ros import progress
from vesselbot_ros.cli import COMMANDS, PROGRESS_COMMANDS, build_parser, main
from vesselbot_ros.config import load_dataclass
from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.sim import warm as warm_module
from vesselbot_ros.sim.scenario import shipped_scenarios
from vesselbot_ros.vessels import cfd
from vesselbot_ros.vessels.network import VesselNetworkParams


class _Terminal(io.StringIO):
    """A stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


@pytest.fixture(autouse=True)
def _no_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(progress.NO_PROGRESS_ENV, raising=False)
    monkeypatch.delenv(progress.FORCE_PROGRESS_ENV, raising=False)


def _small_net() -> VesselNetworkParams:
    """A straight planar vessel on a coarse mesh: its solve takes well under a second."""
    cfd_block = {"inlet_centreline_velocity_m_per_s": 0.025, "mesh_size_m": 8e-4, "grid_spacing_m": 2e-4,
                 "grid_margin_m": 1e-4}
    return load_dataclass(VesselNetworkParams, {"name": "progress_tube", "cfd": cfd_block, "branches": [
        {"name": "a", "parent": "", "x_m": [0.0, 6e-3], "z_m": [0.0, 0.0], "radius_m": [1.5e-3]}]}, "")


def test_bars_only_on_a_terminal_unless_turned_off_or_forced(monkeypatch: pytest.MonkeyPatch) -> None:
    assert progress.wanted(stream=_Terminal())
    assert not progress.wanted(stream=io.StringIO())  # a log, a pipe, a captured stderr
    assert not progress.wanted(no_progress=True, stream=_Terminal())  # --no-progress
    assert progress.wanted(stream=io.StringIO(), force=True)
    monkeypatch.setenv(progress.FORCE_PROGRESS_ENV, "1")
    assert progress.wanted(stream=io.StringIO())
    monkeypatch.setenv(progress.NO_PROGRESS_ENV, "1")  # the user's "no" wins over a forced bar
    assert not progress.wanted(stream=_Terminal(), force=True)
    assert progress.suppressed()


def test_the_captured_stderr_of_a_test_gets_no_bar(capsys: pytest.CaptureFixture[str]) -> None:
    assert not progress.wanted()
    with progress.session(progress.wanted()), progress.step("solve") as report:
        report(1, 2)
        report(2, 2)
    assert capsys.readouterr().err == ""


def test_every_long_command_takes_no_progress_through_the_one_helper() -> None:
    assert PROGRESS_COMMANDS <= COMMANDS.keys()
    positional = {"campaign": ["spec.yaml"]}
    for name in PROGRESS_COMMANDS:
        argv = [name, *positional.get(name, [])]
        assert build_parser(only=name).parse_args([*argv, "--no-progress"]).no_progress is True
        assert build_parser(only=name).parse_args(argv).no_progress is False
    with pytest.raises(SystemExit):  # a quick command does not take it
        build_parser(only="kinds").parse_args(["kinds", "--no-progress"])
    p = argparse.ArgumentParser()
    progress.add_progress_argument(p)
    progress.add_progress_argument(p)  # once per parser: a second call is a no-op, not an argparse conflict
    assert p.parse_args(["--no-progress"]).no_progress


def test_one_line_errors_stay_one_line_with_and_without_the_flag(tmp_path, capsys, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv(progress.FORCE_PROGRESS_ENV, "1")  # even forced: a failing command draws no bar before it fails
    for extra in ([], ["--no-progress"]):
        assert main(["simulate", *extra, "--config", str(tmp_path / "missing.yaml")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("vesselbot simulate: error:"), err


def test_no_step_draws_outside_a_session_and_a_disabled_session_draws_nothing(capsys) -> None:  # type: ignore[no-untyped-def]
    stream = _Terminal()
    with progress.step("outside") as report:
        report(1, 1)
    with progress.session(False, stream), progress.step("disabled") as report:
        assert not progress.active()
        report(1, 1)
    assert stream.getvalue() == "" and capsys.readouterr().err == ""


def test_a_forced_bar_writes_the_step_s_name_and_count_to_stderr(capsys) -> None:  # type: ignore[no-untyped-def]
    with progress.session(progress.wanted(force=True)):
        assert progress.active()
        with progress.step("3-D wall field of tube") as report:
            for done in range(5):
                report(done, 4)
    assert not progress.active()  # the session ends with its block
    err = capsys.readouterr().err
    assert "3-D wall field of tube" in err and "4/4" in err and "100%" in err


def test_the_planar_solve_s_callback_rises_to_its_total() -> None:
    calls: list[tuple[int, int]] = []
    sol = cfd.solve_flow(_small_net(), BloodParams(), progress=lambda done, total: calls.append((done, total)))
    dones = [d for d, _t in calls]
    totals = {t for _d, t in calls}
    assert len(totals) == 1
    total = totals.pop()
    assert dones == sorted(dones) and dones[0] == 0 and dones[-1] == total
    assert len(calls) == sol.picard_iterations + 3  # the start, the assembly, each iteration, the end


def test_a_field_solved_within_a_session_draws_its_named_bar_to_the_end(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("VESSELBOT_CFD_CACHE", str(tmp_path))
    stream = io.StringIO()
    with progress.session(True, stream):
        field = cfd.network_field(_small_net(), BloodParams(), refresh=True)
    out = stream.getvalue()
    assert field.nx > 1 and "2-D flow of progress_tube" in out and "100%" in out


def test_the_warm_up_counts_every_scenario_it_warms(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    ran: list[tuple[str, str]] = []
    monkeypatch.setattr(warm_module, "run_closed_loop", lambda sc, path="compiled": ran.append((sc.name, path)))
    monkeypatch.setattr(warm_module, "run_many", lambda *a, **k: None)
    monkeypatch.setattr(warm_module, "meshed_wall", lambda *a: types.SimpleNamespace(clearance=lambda *point: (0.0, 0.0)))
    walls: list[int] = []
    monkeypatch.setattr(warm_module, "warm_wall_build", lambda: walls.append(1))
    calls: list[tuple[int, int]] = []
    warm_module.warm(lambda done, total: calls.append((done, total)))
    n = len(shipped_scenarios()) + 1  # the shipped scenarios and a multiplexed copy of a planar one
    assert calls == [(i, n) for i in range(n + 1)]
    # both loops of each, the bar counting what was warmed; first the MR-image stages, per tick, on the clinical
    # plan (no shipped scenario runs them), and the wall's build once
    assert len(ran) == 2 * n + 1 and ran[0] == ("clinical_3t_plan", "per_tick") and walls == [1]


@pytest.mark.parametrize("cached", [True, False])
def test_the_wall_build_is_compiled_by_one_part_of_the_warm_up(monkeypatch, cached: bool) -> None:  # type: ignore[no-untyped-def]
    """The bootstrap's three parts run at once: the wall's build is compiled by its own part when every shipped
    tree's lookup is cached (the 3-D part, the longest, then has less to do), else by the 3-D part before it
    builds the missing lookups (one compile, not two at once); planar never, ``all`` always."""
    monkeypatch.setattr(warm_module, "run_closed_loop", lambda *a, **k: None)
    monkeypatch.setattr(warm_module, "run_many", lambda *a, **k: None)
    monkeypatch.setattr(warm_module, "meshed_wall", lambda *a: types.SimpleNamespace(clearance=lambda *point: (0.0, 0.0)))
    monkeypatch.setattr(warm_module, "walls_cached", lambda scenarios=None: cached)
    for scope, expected in (("wall_build", cached), ("trees", not cached), ("planar", False), ("all", True)):
        walls: list[int] = []
        monkeypatch.setattr(warm_module, "warm_wall_build", lambda walls=walls: walls.append(1))
        warm_module.warm(lambda done, total: None, scope=scope)
        assert walls == ([1] if expected else []), scope


def test_walls_cached_is_whether_no_shipped_trees_lookup_would_be_built(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    asked: list[str] = []
    monkeypatch.setattr(warm_module, "check_build", lambda net, blood, quiet=False: asked.append(net.name))
    assert warm_module.walls_cached()
    assert set(asked) == {"carotid_bifurcation_3d", "paper_iiic_artery_3d", "synthetic_tree_3d"}
    monkeypatch.setattr(warm_module, "check_build", lambda net, blood, quiet=False: None if net.name != "synthetic_tree_3d"
                        else object())
    assert not warm_module.walls_cached()


def test_a_session_says_once_when_numba_compiles_our_code_and_nothing_otherwise():
    import io

    import numba

    from vesselbot_ros.progress import COMPILE_NOTICE, session

    def ours(x):  # a function of the package (its module says so), never compiled before: a cache miss
        return x + 1

    def also_ours(x):
        return x * 2

    def theirs(x):
        return x - 1

    ours.__module__ = also_ours.__module__ = "vesselbot_ros.test_compile_notice"
    stream = io.StringIO()
    with session(True, stream):
        assert numba.njit(theirs)(1) == 0  # not our code: no notice
        assert stream.getvalue() == ""
        assert numba.njit(ours)(1) == 2 and numba.njit(also_ours)(2) == 4
    assert stream.getvalue() == COMPILE_NOTICE + "\n"  # once, however much compiles
    quiet = io.StringIO()
    with session(False, quiet):
        def more(x):
            return x + 3
        more.__module__ = ours.__module__
        assert numba.njit(more)(1) == 4
    assert quiet.getvalue() == ""
