"""Stored reference metrics (seeds 0-4 of every shipped scenario) reproduce within 1e-12 relative.

If this fails after a deliberate model change or a library upgrade, the
message names every number that moved; regenerate with
``.venv/bin/python tools/gen_reference_metrics.py`` and commit the file with the reason.
"""

from __future__ import annotations

import copy

from vesselbot_ros.sim.reference_metrics import RTOL, compare, compute_reference, load_reference
from vesselbot_ros.sim.scenario import shipped_scenarios


def test_every_shipped_scenario_matches_the_stored_metrics() -> None:
    stored = load_reference()
    assert stored["rtol"] == RTOL == 1e-12
    assert {r.rsplit("/", 1)[0] for r in stored["runs"]} == set(shipped_scenarios())
    diff = compare(stored, compute_reference())
    assert not diff, "metrics moved against test/data/reference_metrics.json:\n  " + "\n  ".join(diff)


def test_compare_names_every_moved_number() -> None:
    stored = load_reference()
    now = copy.deepcopy(stored)
    run = sorted(now["runs"])[0]
    m = now["runs"][run]
    m["tracking_error_max_m"] *= 1.0 + 3e-12  # beyond 1e-12: reported
    m["estimation_error_rms_m"] *= 1.0 + 5e-13  # within: not reported
    m["plant_steps"] += 1  # integers must be equal
    del m["contact_time_s"]
    now["versions"] = dict(stored["versions"], numpy="99.0")
    diff = compare(stored, now)
    assert any(d.startswith(f"{run} tracking_error_max_m: stored ") for d in diff)
    assert not any("estimation_error_rms_m" in d for d in diff)
    assert any(d.startswith(f"{run} plant_steps:") for d in diff)
    assert f"{run} contact_time_s: missing now" in diff
    assert diff[-1].startswith("library versions: numpy ") and "-> 99.0" in diff[-1]
    assert compare(stored, copy.deepcopy(stored)) == []
