"""Every node started alone with a bad parameter exits at once, naming the parameter."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.graph_spec import LOOP_ROLES as ROLES

# (parameter, value as given on the command line, text the message must contain)
BAD = {
    "plant": ("sim.control_rate_Hz", "-5.0", "sim.control_rate_Hz must be > 0, got -5.0"),
    "imager": ("imager.noise_sigma_m", "-1.0e-4", "imager.noise_sigma_m must be >= 0, got -0.0001"),
    "observer": ("observer.gain_layout", "diagonal", "observer.gain_layout must be one of"),
    "controller": ("controller.gains.k1", "0.0", "controller.gains.k1 must be > 0, got 0.0"),
    "coil_driver": ("coil.saturation_T_per_m", "-0.08", "coil.saturation_T_per_m must be > 0, got -0.08"),
    "reference": ("graph.mode", "turbo", "graph.mode must be one of ['lockstep', 'realtime'], got 'turbo'"),
    "tracker": ("tracker.min_chi2", "-1.0", "tracker.min_chi2 must be > 0, got -1.0"),
}


def test_each_node_alone_rejects_a_bad_parameter(ros):
    procs = {}
    for role in ROLES:
        name, value, _ = BAD[role]
        cmd = [sys.executable, "-m", f"vesselbot_ros.nodes.{role}_node", "--ros-args", "-p", f"{name}:={value}"]
        procs[role] = subprocess.Popen(cmd, env=ros.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for role, p in procs.items():
        out, err = p.communicate(timeout=60)
        assert p.returncode == 2, (role, out, err)
        assert f"vesselbot_{role}: invalid parameter: " in err, err
        assert BAD[role][2] in err, err


def test_unknown_parameter_is_an_error(ros):
    cmd = [sys.executable, "-m", "vesselbot_ros.nodes.controller_node", "--ros-args", "-p", "controller.gain.k1:=3.0"]
    p = subprocess.run(cmd, env=ros.env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 2
    assert "unknown parameter 'controller.gain.k1' (value 3.0)" in p.stderr


def test_bad_config_exits_2_and_creates_no_directory(repo, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nimager:\n  noise_sigma_m: -1\n")
    rec = tmp_path / "rec"
    p = subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", str(bad), "--record-dir", str(rec)],
                       cwd=repo, capture_output=True, text=True, timeout=60)
    assert p.returncode == 2
    assert "imager.noise_sigma_m must be >= 0, got -1" in p.stderr
    assert not rec.exists()


@pytest.mark.timeout(120)
def test_parameters_are_read_only_after_start(ros, tmp_path):
    """``ros2 param set`` on a scenario or graph parameter is refused, not silently ignored."""
    import rclpy
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    from vesselbot_ros.graph_spec import DEFAULT_NAMESPACE, NODE_NAMES
    from vesselbot_ros.testing import NodeProcess, call_service, spin_until

    node = rclpy.create_node("param_probe", context=ros.context)
    ex = rclpy.executors.SingleThreadedExecutor(context=ros.context)
    ex.add_node(node)
    with NodeProcess(["python", "-m", "vesselbot_ros.nodes.controller_node"], ros.env, tmp_path / "ctl.log") as ctl:
        client = node.create_client(SetParameters, f"{DEFAULT_NAMESPACE}/{NODE_NAMES['controller']}/set_parameters")
        assert spin_until(ex, client.service_is_ready, 60), ctl.output()
        for name, value in (("controller.gains.k1", ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=9.0)),
                            ("graph.mode", ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="realtime"))):
            answer = call_service(ex, client, SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)]),
                                  30)  # refused: sending it again changes nothing
            assert answer is not None
            result = answer.results[0]
            assert not result.successful, name
            assert "read-only" in result.reason.lower() or "read only" in result.reason.lower(), result.reason
    ex.shutdown()
    node.destroy_node()


def test_the_tracker_node_refuses_a_scenario_without_mr_frames(ros):
    """The default scenario's imager delivers positions: a tracker node would have nothing to track."""
    cmd = [sys.executable, "-m", "vesselbot_ros.nodes.tracker_node"]
    p = subprocess.run(cmd, env=ros.env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p.stderr
    assert "vesselbot_tracker: invalid parameter: " in p.stderr and "imager.kind 'mri'" in p.stderr, p.stderr
