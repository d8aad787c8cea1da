"""No node outlives its launcher, whatever ends it; the domain stays leased until the last node is gone."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
pytestmark = pytest.mark.wallclock  # the nodes must be gone within 5 s of wall time (judged on a free machine)

from _runs import children, popen_run  # noqa: E402


def _alive(pid: int) -> bool:
    """True if ``pid`` runs (a zombie waiting for its reaper counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


def _start_and_wait_running(repo: Path, *args: str) -> tuple[subprocess.Popen[str], dict[int, str]]:
    launcher = popen_run("--duration", "30", *args, cwd=repo)
    deadline = time.monotonic() + 120
    line = ""
    while time.monotonic() < deadline and "sim " not in line:
        line = launcher.stdout.readline()
        assert line or launcher.poll() is None, launcher.stderr.read()
    assert "sim " in line, "the run never started"
    nodes = {p: c for p, c in children(launcher.pid).items() if "vesselbot_ros" in c}
    return launcher, nodes


def _lock_pids(domain_id: int) -> set[int]:
    """PIDs that took a lock on the lease file of ``domain_id`` still held by some process (from /proc/locks).

    A flock lock lives as long as any process holds its open file, and /proc/locks names the
    process that took it: a launcher's lock held on by its children still shows the launcher's PID.
    The machine's other users lease domains from the same pool, so tests look for their own PIDs.
    """
    from vesselbot_ros.ros_env import _LOCK_DIR

    inode = os.stat(_LOCK_DIR / f"{domain_id}.lock").st_ino
    pids = set()
    for line in Path("/proc/locks").read_text().splitlines():
        parts = line.split()
        fields = parts[1:] if parts[1] != "->" else parts[2:]
        if fields[0] == "FLOCK" and int(fields[4].rsplit(":", 1)[1]) == inode:
            pids.add(int(fields[3]))
    return pids


def _fd_holders(domain_id: int) -> dict[int, str]:
    """Processes with the lease file of ``domain_id`` open: pid -> command line (for failure messages)."""
    from vesselbot_ros.ros_env import _LOCK_DIR

    target = str(_LOCK_DIR / f"{domain_id}.lock")
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if any(os.readlink(f) == target for f in (d / "fd").iterdir()):
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()[:200]
        except OSError:
            continue
    return out


@pytest.mark.timeout(300)
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGHUP])
def test_killing_the_launcher_leaves_no_node_and_frees_the_domain_after(repo, tmp_path, sig, peer_domain):
    dom = peer_domain  # held by this test too (shared): no other run leases it before the launcher does
    bag = tmp_path / "bag"
    launcher, nodes = _start_and_wait_running(repo, "--domain-id", str(dom), "--record-dir", str(bag))
    unjudged = ""
    try:
        assert len(nodes) == 7, nodes  # six nodes + the recorder
        assert launcher.pid in _lock_pids(dom)  # the run holds its domain
        os.kill(launcher.pid, sig)
        t_kill = time.monotonic()
        deadline = t_kill + 60.0
        while time.monotonic() < deadline and any(_alive(p) for p in nodes):
            time.sleep(0.1)
        took = time.monotonic() - t_kill
        left = {p: c for p, c in nodes.items() if _alive(p)}
        assert not left, f"still running {took:.0f} s after {sig.name} of the launcher: {left}"
        if took > 5.0:  # all gone, but slower than the 5 s a free machine takes: judge only if it is free
            from _machine import QUIET_CPU_SHARE, cpu_share

            share = cpu_share()
            if share < QUIET_CPU_SHARE:  # the rest is still checked; the skip comes at the end
                unjudged = (f"the nodes went {took:.1f} s after {sig.name} of the launcher, beyond 5 s, on a loaded "
                            f"machine (a calibration spin got {share:.2f} of a core; load average "
                            f"{os.getloadavg()[0]:.2f}): cannot judge the 5 s bound")
            else:
                pytest.fail(f"the nodes went {took:.1f} s after {sig.name} of the launcher, beyond 5 s, on a free "
                            f"machine (a calibration spin got {share:.2f} of a core)")
    finally:
        if launcher.poll() is None:
            launcher.kill()
        launcher.communicate(timeout=30)
        for p in nodes:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
    # the run's hold on the domain ended with its last node (the kernel frees a dead process's locks
    # when it drops its files, which it may do a moment after the process is gone)
    deadline = time.monotonic() + 30.0  # 2 s on a free machine: the bound only says it is freed at all
    while time.monotonic() < deadline and launcher.pid in _lock_pids(dom):
        time.sleep(0.05)
    assert launcher.pid not in _lock_pids(dom), _fd_holders(dom)
    # and the recorder, stopped by the parent-death signal, finalised its bag
    from vesselbot_ros.bag.reader import open_bag

    info = open_bag(bag)
    assert info.consistent, info.problems
    assert info.topic("/vesselbot/truth").count > 0
    if unjudged:
        pytest.skip(unjudged)


@pytest.mark.timeout(300)
def test_the_domain_stays_leased_while_a_node_runs(repo, tmp_path):
    """A node that outlives the launcher's own exit keeps the lease: no second run can take its domain."""
    from vesselbot_ros.launch.processes import ChildProcess
    from vesselbot_ros.ros_env import allocate_domain

    lease = allocate_domain()
    dom = lease.domain_id
    # a child holding the lease, as the launcher starts its nodes; the launcher's own hold ends here
    child = ChildProcess("sleeper", ["sleep", "30"], dict(os.environ), tmp_path / "sleeper.log", hold_fds=lease.fds)
    lease.release()
    try:
        assert os.getpid() in _lock_pids(dom)  # our lock, held on by the child alone
        with pytest.raises(RuntimeError, match="in use"):
            allocate_domain(dom)
    finally:
        child.stop(5.0, signal.SIGKILL)
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and os.getpid() in _lock_pids(dom):
        time.sleep(0.05)
    assert os.getpid() not in _lock_pids(dom)  # gone with the child
