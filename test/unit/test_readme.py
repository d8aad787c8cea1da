"""Every test that docs/faults_and_safety.md's table cites exists."""

from __future__ import annotations

import re


def test_every_cited_test_exists(repo):
    section = (repo / "docs" / "faults_and_safety.md").read_text()
    cited = re.findall(r"`(test/[\w/]+\.py)::(\w+)`", section)
    # "`::name`" continues the previous file
    rows = re.findall(r"`(?:(test/[\w/]+\.py))?::(\w+)`", section)
    assert len(cited) >= 10
    current = None
    for path, func in rows:
        current = path or current
        source = (repo / current).read_text()
        assert re.search(rf"^(async )?def {func}\(", source, re.M), f"{current}::{func} is cited but does not exist"
