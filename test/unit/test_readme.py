"""Every test that README's "Faults and safety" table cites exists."""

from __future__ import annotations

import re


def test_every_cited_test_exists(repo):
    readme = (repo / "README.md").read_text()
    section = readme.split("## Faults and safety", 1)[1].split("\n## ", 1)[0]
    cited = re.findall(r"`(test/[\w/]+\.py)::(\w+)`", section)
    # "`::name`" continues the previous file
    rows = re.findall(r"`(?:(test/[\w/]+\.py))?::(\w+)`", section)
    assert len(cited) >= 10
    current = None
    for path, func in rows:
        current = path or current
        source = (repo / current).read_text()
        assert re.search(rf"^(async )?def {func}\(", source, re.M), f"{current}::{func} is cited but does not exist"
