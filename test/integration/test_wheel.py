"""The wheel: built, installed into a fresh venv, ``vesselbot`` run with no arguments from a temporary directory.

The fresh venv gets only our wheel.  Its dependencies (the ROS 2 Jazzy wheels
and the interfaces built with rosidl, which take minutes to install) come from
the project's ``.venv`` as an underlay, the way a ROS workspace overlays an
underlay: one ``.pth`` line naming its site-packages, ``AMENT_PREFIX_PATH``
and the library path.  Nothing of the checkout is importable in the fresh
venv: the test checks that ``vesselbot_ros`` is imported from the wheel and
that the scenario is the wheel's shipped copy.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _underlay_env(venv: Path) -> dict[str, str]:
    site = Path(sysconfig.get_paths()["purelib"])
    libs = [str(Path(sys.prefix) / "lib")] + sorted(str(p) for p in site.glob("ros_*.libs"))
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV"))}
    env.update(LD_LIBRARY_PATH=os.pathsep.join(libs), _ROS_WHEELS_BOOTSTRAP_COMPLETE="1",
               AMENT_PREFIX_PATH=sys.prefix, PATH=os.pathsep.join([str(venv / "bin"), "/usr/bin", "/bin"]),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return env


@pytest.mark.slow  # about a minute: a wheel, a venv, a recorded run
@pytest.mark.timeout(1200)
def test_wheel_in_a_fresh_venv_runs_the_default_scenario_from_a_temporary_directory(tmp_path):
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist),
                    str(REPO)], check=True, capture_output=True, text=True, timeout=300)
    wheel = next(dist.glob("vesselbot_ros-*.whl"))
    venv = tmp_path / "venv"
    subprocess.run([getattr(sys, "_base_executable", sys.executable), "-m", "venv", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)], check=True,
                   capture_output=True, timeout=300)
    fresh_site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                     check=True, capture_output=True, text=True).stdout.strip())
    (fresh_site / "_vesselbot_underlay.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    env = _underlay_env(venv)
    work = tmp_path / "anywhere"
    work.mkdir()

    where = subprocess.run([str(py), "-c", "import vesselbot_ros, vesselbot_ros.config as c; "
                            "print(vesselbot_ros.__file__); print(c.shipped_config_dir())"],
                           cwd=work, env=env, capture_output=True, text=True, timeout=120)
    assert where.returncode == 0, where.stderr
    module, config_dir = where.stdout.split()
    assert module.startswith(str(fresh_site)) and config_dir == str(venv / "share" / "vesselbot_ros" / "config")

    # what tools/bootstrap.sh does after installing for `make run` (scope run: the default scenario, which the run
    # below flies): fill numba's cache (beside the installed modules), so that the nodes start without compiling.
    # numba keys its cache on each source's content, which the wheel's copy shares with the checkout, so the
    # checkout's cache (bootstrap compiled it) is copied in and warm() only loads it: compiling it again costs
    # this test about 100 s, and bootstrap already compiles it from nothing
    checkout = REPO / "vesselbot_ros"
    for cached in checkout.rglob("__pycache__/*"):
        if cached.suffix in (".nbi", ".nbc") or cached.name == "numba.sources.sha256":
            dest = fresh_site / "vesselbot_ros" / cached.relative_to(checkout)
            dest.parent.mkdir(exist_ok=True)
            shutil.copy2(cached, dest)
    warm = subprocess.run([str(py), "-c", "from vesselbot_ros.sim.warm import warm; warm(scope='run')"], cwd=work, env=env,
                          capture_output=True, text=True, timeout=600)
    assert warm.returncode == 0, warm.stderr[-3000:]

    listing = subprocess.run([str(venv / "bin" / "vesselbot"), "scenarios"], cwd=work, env=env, capture_output=True,
                             text=True, timeout=120)
    assert listing.returncode == 0, listing.stderr
    names = [ln.split()[0] for ln in listing.stdout.splitlines() if ln and not ln[0].isspace()]  # not a description
    from vesselbot_ros.sim.scenario import shipped_scenarios

    assert names == sorted(shipped_scenarios())  # the wheel ships every scenario of the checkout
    assert "(default)" in next(ln for ln in listing.stdout.splitlines() if ln.startswith("sound_small_artery "))

    run = subprocess.run([str(venv / "bin" / "vesselbot"), "run"], cwd=work, env=env, capture_output=True,
                         text=True, timeout=480)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    # the same scenario as `make run` (its default CONFIG is empty: run's default)
    assert run.stdout.startswith("vesselbot run: sound_small_artery seed 0, lockstep, 2.0 s at 1000 Hz")
    assert "CONFIG ?=\n" in (REPO / "Makefile").read_text()
    bags = list((work / "runs").glob("*_sound_small_artery"))
    assert len(bags) == 1 and (bags[0] / "metadata.yaml").is_file()
    assert "run finished: 2000 ticks" in run.stdout and "sound_small_artery: tracking error after 0.6 s max " in run.stdout
