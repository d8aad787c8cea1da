#!/usr/bin/env python3
"""Regenerate test/data/reference_metrics.json: metrics of seeds 0-4 of every shipped scenario.

Run it (``.venv/bin/python tools/gen_reference_metrics.py``) after a deliberate
change of the model or of a pinned library, and commit the file with the
reason; ``test/unit/sim/test_reference_metrics.py`` compares every run against
it within 1e-12 relative.
"""

from __future__ import annotations

import json
import sys

from vesselbot_ros.atomic_io import write_text
from vesselbot_ros.sim.reference_metrics import REFERENCE_FILE, compare, compute_reference, load_reference


def main() -> int:
    now = compute_reference()
    if REFERENCE_FILE.is_file():
        diff = compare(load_reference(), now)
        print(f"{len(diff) - 1 if diff else 0} numbers changed" + ("".join(f"\n  {d}" for d in diff)))
    REFERENCE_FILE.parent.mkdir(parents=True, exist_ok=True)
    write_text(REFERENCE_FILE, json.dumps(now, indent=1, sort_keys=True) + "\n")
    print(f"wrote {REFERENCE_FILE} ({len(now['runs'])} runs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
