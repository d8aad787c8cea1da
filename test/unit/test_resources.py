"""The one resource check (vesselbot_ros.resources): its budget, under a limit too, and its one-line refusals."""

from __future__ import annotations

import subprocess
import sys

import pytest

from vesselbot_ros import resources
from vesselbot_ros.errors import ConfigError
from vesselbot_ros.resources import SETUP_TIME_BUDGET_S, fmt_bytes, memory_budget_bytes, require_fits


def test_the_budget_is_half_the_machine_and_half_what_a_limit_leaves() -> None:
    import os

    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert 0 < memory_budget_bytes() <= total // 2
    code = ("import resource; resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))\n"
            "from vesselbot_ros.resources import memory_budget_bytes, _status_bytes\n"
            "print(memory_budget_bytes(), _status_bytes('VmSize'))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True).stdout
    budget, used = (int(v) for v in out.split())
    assert budget == ((2 << 30) - used) // 2 or budget < ((2 << 30) - used) // 2 + 2**20  # VmSize moves by pages


def test_a_step_that_does_not_fit_is_one_line_naming_key_value_and_estimate() -> None:
    require_fits("k", 3, 1000.0, 10.0, what="a step", memory_budget=2000)
    with pytest.raises(ConfigError, match=r"^cfd\.mesh_size_m=1e-06: the solve needs about 9\.3 GiB of memory, more than "
                                          r"the 1\.0 GiB a step may use \(half of this machine's memory, or of its limit\): "
                                          r"raise it$"):
        require_fits("cfd.mesh_size_m", 1e-6, 1e10, None, what="the solve", hint="raise it", memory_budget=2**30)
    with pytest.raises(ConfigError, match=r"^n=5 points: a solve would take about 2\.78 h \(1\.0 KiB of memory\), more than "
                                          r"the 30 min a set-up step may take$"):
        require_fits("n", "5 points", 1024, 1e4, what="a solve", memory_budget=2**30)
    with pytest.raises(ConfigError, match="needs about nan TiB"):
        require_fits("x", 1, float("nan"), what="a step", memory_budget=2**30)
    assert SETUP_TIME_BUDGET_S == 1800.0 and fmt_bytes(3 * 2**30) == "3.0 GiB"


def test_the_run_check_reads_the_same_budget() -> None:
    from vesselbot_ros.sim import scenario

    assert scenario._memory_budget_bytes is resources.memory_budget_bytes
