"""Helpers of the fault / safety integration tests: run `vesselbot run`, find its node processes, read bags."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent


def write_config(tmp: Path, base: str = "sound_small_artery", **dotted: Any) -> Path:
    """A copy of ``config/<base>.yaml`` with dotted keys overridden; returns its path."""
    doc = yaml.safe_load((REPO / "config" / f"{base}.yaml").read_text())
    for key, value in dotted.items():
        *parents, leaf = key.split("__")
        node = doc
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    tmp.mkdir(parents=True, exist_ok=True)
    out = tmp / f"{base}_test.yaml"
    out.write_text(yaml.safe_dump(doc))
    return out


def run_cmd(*args: str) -> list[str]:
    """argv of ``vesselbot run ARGS``."""
    return [sys.executable, "-m", "vesselbot_ros.cli", "run", *args]


def popen_run(*args: str, cwd: Path) -> subprocess.Popen[str]:
    """Start ``vesselbot run ARGS`` with pipes."""
    return subprocess.Popen(run_cmd(*args), cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def children(pid: int) -> dict[int, str]:
    """Direct child processes of ``pid``: pid -> command line (from /proc)."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
    return out


def node_pid(launcher_pid: int, role: str) -> int:
    """PID of the node process of ``role`` started by the launcher ``launcher_pid``."""
    pids = [p for p, c in children(launcher_pid).items() if f"vesselbot_ros.nodes.{role}_node" in c]
    assert len(pids) == 1, children(launcher_pid)
    return pids[0]


def hostile_env(domain_id: int, log_dir: Path) -> dict[str, str]:
    """Environment for a helper node joining the run on ``domain_id``."""
    from vesselbot_ros.ros_env import ros_environment

    env = ros_environment(domain_id, log_dir)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    return env


def diagnostics(bag: Path, node_name: str) -> list[tuple[int, dict[str, str], int]]:
    """(log time ns, key/values, level) of every recorded DiagnosticStatus of ``node_name``."""
    from vesselbot_ros.bag.reader import iter_messages

    out = []
    for m in iter_messages(bag, topics=["/diagnostics"]):
        for st in m.decode().status:
            if st.name == node_name:
                lvl = st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")
                out.append((m.log_time_ns, {kv.key: kv.value for kv in st.values}, lvl))
    return out


def assert_coil_invariants(ts: dict[str, np.ndarray], u_sat: float, slew: float, dt: float) -> None:
    """Every coil/state message: finite, |applied| <= U_sat, per-axis step <= slew * dt, ticks consecutive."""
    t = ts["coil.t_s"]
    g = ts["coil.applied"][:, [0, 2]]
    assert len(t) > 10
    assert np.all(np.isfinite(g)), "non-finite applied gradient"
    assert np.all(ts["coil.applied"][:, 1] == 0.0)
    norms = np.hypot(g[:, 0], g[:, 1])
    worst = int(np.argmax(norms))
    assert norms[worst] <= u_sat * (1 + 1e-12), f"|U_a| = {norms[worst]} T/m > U_sat = {u_sat} at t = {t[worst]}"
    np.testing.assert_allclose(np.diff(t), dt, rtol=0, atol=1e-9)  # one message per tick, none lost
    # the coil is at zero one tick before the first message (it may take one slew step by then)
    steps = np.abs(np.diff(np.vstack([np.zeros((1, 2)), g]), axis=0))
    dts = np.diff(np.concatenate([[t[0] - dt], t]))
    allowed = slew * np.maximum(dts, 0.0)[:, None] * (1 + 1e-9) + 1e-15
    bad = np.argwhere(steps > allowed)
    assert bad.size == 0, (f"slew limit {slew} T/m/s exceeded at t = {t[bad[0][0]]}: step {steps[bad[0][0]]} T/m "
                           f"in {dts[bad[0][0]]} s")


def start_node(role: str, env: dict[str, str], log_path: Path, **params: Any) -> Any:
    """Start the node ``role`` alone (a :class:`vesselbot_ros.testing.NodeProcess`) with ``-p name:=value`` params.

    Keys use ``__`` for dots (``imager__frame_rate_Hz=1000.0``); values are written as YAML scalars.
    """
    from vesselbot_ros.testing import NodeProcess

    argv = ["python", "-m", f"vesselbot_ros.nodes.{role}_node", "--ros-args"]
    for key, value in params.items():
        argv += ["-p", f"{key.replace('__', '.')}:={yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()}"]
    env = dict(env)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    return NodeProcess(argv, env, log_path)


def truth_msg(k: int, dt_s: float, p_xz: tuple[float, float], frame_id: str = "vessel") -> Any:
    """A ``PlantState`` for tick ``k`` (stamp ``k * dt_s``) at position ``p_xz`` (m)."""
    from vesselbot_msgs.msg import PlantState

    from vesselbot_ros.nodes import conversions as cv

    msg = PlantState(tick=k, position=cv.point(p_xz), vessel_diameter=3e-3)
    msg.header = cv.header(cv.tick_time(k, dt_s))
    msg.header.frame_id = frame_id
    return msg


def status_values(arr: Any, node_name: str) -> list[tuple[dict[str, str], int]]:
    """(key/values, level) of the statuses of ``node_name`` in one DiagnosticArray."""
    out = []
    for st in arr.status:
        if st.name == node_name:
            lvl = st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")
            out.append(({kv.key: kv.value for kv in st.values}, lvl))
    return out


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now (the kernel's choice)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def node_client(script: str, *args: str) -> subprocess.Popen[str]:
    """Start ``node tools/js/SCRIPT ARGS`` (Foxglove's own client) with pipes."""
    import shutil

    from vesselbot_ros.testing import JS_DIR

    node = shutil.which("node")
    assert node is not None and (JS_DIR / "node_modules").is_dir(), "node / tools/js not installed: make bootstrap"
    return subprocess.Popen([node, str(JS_DIR / script), *args], cwd=JS_DIR, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def last_json(proc: subprocess.Popen[str], timeout: float) -> Any:
    """Wait (bounded) for ``proc`` and return the last JSON line it printed."""
    import json

    out, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, f"exit {proc.returncode}: {err[-2000:]}"
    lines = [ln for ln in out.splitlines() if ln.startswith("{")]
    assert lines, f"no JSON printed: {out[-1000:]} {err[-1000:]}"
    return json.loads(lines[-1])
