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


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    return re.sub(r"\s", "-", re.sub(r"[^\w\s-]", "", text))


def _pages(repo):
    return [repo / "README.md", *sorted((repo / "docs").glob("*.md"))]


def test_every_link_of_the_readme_and_docs_leads_somewhere(repo):
    """A relative link names a file of the repository, and its #anchor a heading of that page."""
    broken, checked = [], 0
    for page in _pages(repo):
        text = page.read_text(encoding="utf-8")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+://|mailto:", target):
                continue
            checked += 1
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.relative_to(repo)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md":
                anchors = {_anchor(h) for h in re.findall(r"^#+ (.+)$", dest.read_text(encoding="utf-8"), re.M)}
                if anchor not in anchors:
                    broken.append(f"{page.relative_to(repo)}: {target} (no such heading)")
    assert checked >= 20 and broken == []


def test_every_repository_path_the_docs_name_exists(repo):
    """`bench/x.py`, `tools/x.py`, `docs/x.md`, `config/x.yaml`, `test/...py`, `vesselbot_ros/...py` in code spans."""
    missing, named = [], 0
    pattern = re.compile(r"`((?:bench|tools|docs|config|test|vesselbot_ros|examples)/[\w./-]+\.(?:py|md|yaml|csv|json|sh))`")
    for page in _pages(repo):
        for path in pattern.findall(page.read_text(encoding="utf-8")):
            named += 1
            if "<" not in path and "*" not in path and not (repo / path).exists():
                missing.append(f"{page.relative_to(repo)}: {path}")
    assert named >= 20 and missing == []


def test_the_index_lists_every_page_of_the_manual(repo):
    index = (repo / "docs" / "index.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"\]\(([\w-]+\.md)\)", index))
    assert {p.name for p in (repo / "docs").glob("*.md")} - {"index.md"} <= listed
