"""The bootstrap: a broken interface fails loudly; an up-to-date tree does nothing."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
VENV = Path(sys.prefix)


def _clean_env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    env.pop("LD_LIBRARY_PATH", None)
    return env


@pytest.mark.skipif(shutil.which("cmake") is None or shutil.which("ninja") is None, reason="needs cmake and ninja")
def test_broken_msg_file_fails_with_the_rosidl_error_and_installs_nothing(tmp_path):
    src = tmp_path / "msg_defs"
    shutil.copytree(REPO / "msg_defs", src)
    (src / "msg" / "CoilState.msg").write_text("float64 applied  # ok\nnot_a_type!! broken field\n")
    before = sorted(p.name for p in (VENV / "share" / "vesselbot_msgs" / "msg").glob("*"))
    proc = subprocess.run(
        ["bash", str(REPO / "tools" / "build_interfaces.sh"), str(VENV), str(src), str(tmp_path / "build")],
        capture_output=True, text=True, env=_clean_env(), timeout=300,
    )
    assert proc.returncode != 0
    assert "FAILED" in proc.stderr
    # the rosidl parser's own complaint reaches the user
    assert "CoilState.msg" in proc.stderr or "not_a_type" in proc.stderr, proc.stderr
    after = sorted(p.name for p in (VENV / "share" / "vesselbot_msgs" / "msg").glob("*"))
    assert after == before  # the installed interfaces were not touched


def test_second_bootstrap_is_a_no_op():
    proc = subprocess.run(["bash", str(REPO / "tools" / "bootstrap.sh")], capture_output=True, text=True,
                          env=_clean_env(), timeout=600, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    # nothing to do: no step announces itself
    assert "installing" not in proc.stdout and "building" not in proc.stdout, proc.stdout
