"""The registry of stage kinds: built-in kinds, a user's module:Class, entry points, and their errors."""

from __future__ import annotations

import dataclasses
import importlib.metadata
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.backstepping import ControllerParams
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.sim import kinds
from vesselbot_ros.sim.closed_loop import REPLACEABLE, build_stages, run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, scenario_from_mapping, shipped_scenarios

REPO = Path(__file__).resolve().parents[3]
PLUGINS = REPO / "test" / "plugins"
PLUGIN = "vesselbot_test_plugin:IntegralController"


@pytest.fixture
def plugins(monkeypatch):
    """The test plug-in package importable, as a user's PYTHONPATH makes it."""
    monkeypatch.syspath_prepend(str(PLUGINS))


def _scenario(duration: float = 0.2, **sections):
    base = load_scenario(shipped_scenarios()["sound_small_artery"], duration=duration).to_mapping()
    base.update(sections)
    return scenario_from_mapping(base)


def test_every_role_has_its_default_kind_built_in_and_compiled() -> None:
    assert tuple(kinds.SECTIONS) == kinds.ROLES and set(kinds.DEFAULT_KINDS) == set(kinds.ROLES)
    assert set(kinds.ROLES) == set(REPLACEABLE)
    for role, name in kinds.DEFAULT_KINDS.items():
        k = kinds.find(role, name)
        # the tracker runs per tick, on the frames of an imager that delivers them (none with the default imager)
        assert (k.compiled or role == "tracker") and k.source == "built-in" and k.role == role
    st = build_stages(_scenario())
    assert st.tracker is None
    for role in kinds.ROLES:  # each built stage is recognised as its kind's, and follows its role's protocol
        stage = getattr(st, role)
        if role == "tracker":
            continue
        assert kinds.kind_of(role, stage) is not None
        assert isinstance(stage, kinds._PROTOCOLS[role])
    sc = _scenario()
    assert sc.controller.kind == "backstepping" and sc.physics.kind == "vessel" and sc.imager.kind == "mri"


def test_a_users_controller_runs_by_module_and_class_with_its_own_validated_parameters(plugins) -> None:
    sc = _scenario(controller={"kind": PLUGIN, "ki_per_s3": 650.0})
    assert type(sc.controller).__name__ == "IntegralParams" and sc.controller.ki_per_s3 == 650.0
    assert sc.to_mapping()["controller"] == {"kind": PLUGIN, "kp_per_s2": 500.0, "kd_per_s": 45.0, "ki_per_s3": 650.0}
    assert scenario_from_mapping(sc.to_mapping()) == sc  # the mapping round-trips through the one loader
    a = run_closed_loop(sc, seed=4)
    b = run_closed_loop(sc, seed=4)
    assert a.path == "per_tick"  # the compiled loop does not have it: the per-tick loop runs it
    assert a.metrics == b.metrics and np.array_equal(a.timeseries["g_cmd"], b.timeseries["g_cmd"])
    assert a.metrics["tracking_error_max_m"] < 1e-3  # it actually steers (a PID with the model fed forward)
    # it differs from law (24), so the numbers are its own
    assert a.metrics["tracking_error_max_m"] != run_closed_loop(_scenario(), seed=4).metrics["tracking_error_max_m"]
    st = build_stages(sc, seed=4)
    assert kinds.kind_of("controller", st.controller).name == PLUGIN
    with pytest.raises(ModelInputError, match=r"user stage\(s\) \['controller'\]"):
        run_closed_loop(sc, path="compiled")


def test_the_controller_gets_the_graphs_estimate_in_both_loops(plugins) -> None:
    """What travels between the nodes: position, velocity, age, flow scale; no innovation or flags."""
    seen = []

    class Spy:
        def command(self, t_s, estimate, ref):
            seen.append(estimate)
            return kinds.ControlCommand(np.zeros(2), np.zeros(2), "ok")

    run_closed_loop(_scenario(0.05), stages={"controller": Spy()})
    assert len(seen) == 50
    assert all(not e.used_measurement and not e.rejected and np.array_equal(e.innovation, np.zeros(2)) for e in seen)
    assert math.isinf(seen[0].time_since_measurement_s) or seen[0].time_since_measurement_s >= 0.0


@pytest.mark.parametrize("name, match", [
    ("nope", r"controller\.kind: unknown controller kind 'nope'; known: \['action_replay', 'adaptive_backstepping', "
             r"'backstepping', 'policy', 'predictive'\]"),
    ("no_such_module_x:Cls", r"controller\.kind: module 'no_such_module_x' of kind .* does not import: ModuleNotFoundError"),
    ("vesselbot_test_plugin:Missing", r"controller\.kind: module 'vesselbot_test_plugin' has no 'Missing'"),
    ("vesselbot_test_plugin:NotAStage", r"controller\.kind: class NotAStage needs ROLE"),
])
def test_a_kind_that_cannot_be_used_is_one_error_naming_the_key(plugins, name, match) -> None:
    with pytest.raises(ConfigError, match=match):
        _scenario(controller={"kind": name})


def test_a_kind_of_another_role_and_bad_parameters_are_refused(plugins) -> None:
    with pytest.raises(ConfigError, match=r"observer\.kind: 'vesselbot_test_plugin:IntegralController' is a controller kind"):
        _scenario(observer={"kind": PLUGIN})
    with pytest.raises(ConfigError, match=r"unknown key controller\.gains"):
        _scenario(controller={"kind": PLUGIN, "gains": {"k1": 1.0}})
    with pytest.raises(ConfigError, match=r"controller\.kp_per_s2 must be > 0, got -1"):
        _scenario(controller={"kind": PLUGIN, "kp_per_s2": -1.0})
    with pytest.raises(ConfigError, match=r"imager\.kind: unknown imager kind 'ct'; known: \['mr_images', 'mri'\]"):
        _scenario(imager={"kind": "ct"})


def test_switching_a_sections_kind_on_the_command_line_drops_the_old_kinds_keys_only(plugins) -> None:
    path = shipped_scenarios()["sound_small_artery"]
    sc = load_scenario(path, sets=[f"controller.kind={PLUGIN}", "controller.kd_per_s=30"], duration=0.1)
    assert sc.controller.kd_per_s == 30.0 and sc.controller.kp_per_s2 == 500.0
    with pytest.raises(ConfigError, match=r"unknown key controller\.kx"):  # a wrong key of the new kind still fails
        load_scenario(path, sets=[f"controller.kind={PLUGIN}", "controller.kx=3"], duration=0.1)
    # a kind with the same parameters keeps the section (the gains stay)
    sc = load_scenario(path, sets=["controller.kind=adaptive_backstepping", "controller.gains.k1=7"], duration=0.1)
    assert isinstance(sc.controller, ControllerParams) and sc.controller.gains.k1 == 7.0


def test_an_installed_package_registers_kinds_through_the_entry_point_group(plugins, monkeypatch) -> None:
    ep = importlib.metadata.EntryPoint(name="integral_pid", value=PLUGIN, group=kinds.ENTRY_POINT_GROUP)
    calls = []

    def entry_points(group):
        calls.append(group)
        return [ep]

    monkeypatch.setattr(kinds.importlib.metadata, "entry_points", entry_points)
    monkeypatch.setattr(kinds, "_ENTRY_POINTS_LOADED", False)
    monkeypatch.setattr(kinds, "_REGISTRY", dict(kinds._REGISTRY))
    sc = _scenario(controller={"kind": "integral_pid", "kp_per_s2": 400.0})
    assert calls == [kinds.ENTRY_POINT_GROUP]
    k = kinds.find("controller", "integral_pid")
    assert k.source.startswith("entry point") and sc.controller.kp_per_s2 == 400.0
    assert "integral_pid" in [k.name for k in kinds.kinds("controller")]


def test_a_plant_kind_must_keep_the_physics_the_model_reads() -> None:
    @dataclasses.dataclass(frozen=True)
    class Odd:
        kind: str = "odd"

    with pytest.raises(ConfigError, match="a plant kind's params must subclass PhysicsParams"):
        kinds.StageKind("plant", "odd", Odd, lambda ctx: None)
    with pytest.raises(ConfigError, match="needs a 'kind: str' field"):
        kinds.StageKind("controller", "odd", dataclasses.make_dataclass("P", [("a", int)]), lambda ctx: None)


def test_fingerprint_follows_the_users_module_source(tmp_path, monkeypatch) -> None:
    src = (PLUGINS / "vesselbot_test_plugin.py").read_text()
    (tmp_path / "fp_plugin.py").write_text(src)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(kinds, "_REGISTRY", dict(kinds._REGISTRY))
    sc = _scenario(controller={"kind": "fp_plugin:IntegralController"})
    assert kinds.fingerprint(_scenario()) == ""  # built-in kinds only: nothing to add
    first = kinds.fingerprint(sc)
    assert len(first) == 16
    (tmp_path / "fp_plugin.py").write_text(src + "\n# changed\n")
    assert kinds.fingerprint(sc) != first


def test_vesselbot_kinds_lists_and_checks(plugins) -> None:
    env_path = str(PLUGINS)
    out = subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "kinds"], capture_output=True, text=True,
                         timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    for role, name in kinds.DEFAULT_KINDS.items():
        assert f"{role} (scenario section '{kinds.SECTIONS[role]}'" in out.stdout and f"  {name} " in out.stdout
    chk = subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "kinds", "--check", PLUGIN], capture_output=True,
                         text=True, timeout=120, cwd=REPO, env={**os.environ, "PYTHONPATH": env_path})
    assert chk.returncode == 0, chk.stderr
    assert "IntegralParams(kp_per_s2=500.0, kd_per_s=45.0, ki_per_s3=800.0)" in chk.stdout
    bad = subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "kinds", "--check", "observer=foo"],
                         capture_output=True, text=True, timeout=120, cwd=REPO)
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "unknown observer kind 'foo'" in bad.stderr


@pytest.mark.parametrize("section, kind, columns", [
    ("controller", "CompiledPD", ("p_true", "x_hat", "g_cmd", "u_cmd", "g_applied", "flow_scale_hat")),
    ("reference", "GlideReference", ("p_ref", "p_true", "x_hat", "g_applied")),
])
def test_a_users_compiled_kind_runs_in_the_compiled_loop_with_the_per_tick_numbers(plugins, section, kind,
                                                                                    columns) -> None:
    """One module whose class gives its role's compiled form: the compiled loop runs it with no branch of its own
    (a controller: a numba step of the one signature; a reference, as every role may: its samples at the tick
    times), with the numbers of the per-tick loop."""
    name = f"vesselbot_test_plugin:{kind}"
    sc = _scenario(0.3, **{section: {"kind": name}})
    k = kinds.find(section, name)
    assert k.compiled and k.compile is not None
    fast = run_closed_loop(sc, seed=2)
    slow = run_closed_loop(sc, seed=2, path="per_tick")
    assert (fast.path, slow.path) == ("compiled", "per_tick")
    assert fast.metrics == slow.metrics
    for col in columns:
        assert np.array_equal(fast.timeseries[col], slow.timeseries[col]), col
    if section == "controller":  # the law tracks
        assert fast.metrics["tracking_error_max_m"] < 1e-3
    else:  # the reference glides along x
        assert fast.timeseries["p_ref"][-1, 0] > fast.timeseries["p_ref"][0, 0]


def test_checked_command_contains_every_bad_answer_of_a_controller() -> None:
    """kinds.checked_command (both loops' and the nodes' rule, issue 38): a bare (2,) array is a command; NaN/inf,
    an exception, None, a wrong shape or an unknown status is a rejection with its code and a NaN gradient for the
    coil; a non-finite estimate is not given to the controller; a deliberate VesselbotError still stops the run."""
    from vesselbot_ros.control.backstepping import ControlCommand

    z = np.zeros(2)

    class Answer:
        def __init__(self, value):
            self.value, self.calls = value, 0

        def command(self, t_s, estimate, ref):
            self.calls += 1
            if isinstance(self.value, BaseException):
                raise self.value
            return self.value

    def check(value, x=z):
        return kinds.checked_command(Answer(value), 0.0, x, z, 0.0, 1.0, z, z, z, 2)

    cmd, why, _ = check(np.array([0.01, -0.02]))
    assert why == kinds.REJECT_NONE and cmd.status == "ok"
    np.testing.assert_array_equal(cmd.gradient_T_per_m, [0.01, -0.02])
    assert np.all(np.isnan(cmd.u_m_per_s2))
    cmd, why, _ = check(ControlCommand(np.array([0.01, 0.0]), np.ones(2), "stale"))
    assert why == kinds.REJECT_NONE and cmd.status == "stale"
    for value, code, detail in [
        (ControlCommand(np.array([np.nan, 0.0]), z, "ok"), kinds.REJECT_NONFINITE, "non-finite"),
        (np.array([np.inf, 0.0]), kinds.REJECT_NONFINITE, "non-finite"),
        (ValueError("boom"), kinds.REJECT_RAISED, "ValueError: boom"),
        (None, kinds.REJECT_MALFORMED, "returned NoneType, not a command"),
        (np.zeros(3), kinds.REJECT_MALFORMED, "gradient of shape (3,), expected (2,)"),
        (ControlCommand(z, z, "fine"), kinds.REJECT_MALFORMED, "status 'fine', not one of ['ok', 'stale', 'nonfinite']"),
    ]:
        cmd, why, text = check(value)
        assert (why, text) == (code, detail)
        assert cmd.status == "nonfinite" and not np.all(np.isfinite(cmd.gradient_T_per_m))
    ctrl = Answer(np.zeros(2))
    _, why, _ = kinds.checked_command(ctrl, 0.0, np.array([np.nan, 0.0]), z, 0.0, 1.0, z, z, z, 2)
    assert why == kinds.REJECT_ESTIMATE and ctrl.calls == 0
    with pytest.raises(ModelInputError, match="deliberate"):
        check(ModelInputError("deliberate"))


# ---- one loop on any number of axes (issue 40): a role's kind builds one class for the plane and for space ----
def _stage_class(stage: object) -> tuple[type, ...]:
    """The class of a built stage, and of the stage it wraps (the scanner's gated imager and coil)."""
    inner = getattr(stage, "inner", None)
    return (type(stage),) if inner is None else (type(stage), type(inner))


@pytest.mark.parametrize("role", (*kinds.ROLES, "model"))
def test_a_roles_built_in_kind_is_one_class_in_the_plane_and_in_a_3d_tree(role: str) -> None:
    """The same scenario options in the straight vessel and in a 3-D tree, continuous and multiplexed: each role's
    stage (and the controller's and observer's model) is built from one class (the axis count is its data), never a
    planar class and a 3-D twin."""
    seq = ["sequence.mode=multiplexed", "sequence.tracking_window_s=0.002", "sequence.dead_time_s=0.001",
           "sequence.propulsion_window_s=0.004", "sequence.latency_s=0.001", "imager.frame_rate_Hz=500",
           "controller.duty_compensation=sequence", "sim.duration_s=0.1"]
    for sets in ([], seq):
        planar = build_stages(load_scenario(shipped_scenarios()["sound_small_artery"], sets=sets))
        tree = build_stages(load_scenario(shipped_scenarios()["paper_iiic_network_upper_3d"], sets=sets))
        assert getattr(getattr(tree, role), "dims", 3) == 3 and getattr(getattr(planar, role), "dims", 2) == 2
        assert _stage_class(getattr(planar, role)) == _stage_class(getattr(tree, role)), (role, sets)
