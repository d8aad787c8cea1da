#!/usr/bin/env python3
"""Solve the flow of every shipped scenario's vessel network afresh and ship the sampled fields in config/cfd/.

Run it (``.venv/bin/python tools/ship_cfd_fields.py``) after a change of a shipped
network, of the CFD settings or code (``cfd.CACHE_VERSION``) or of a shipped
scenario's blood model, then ``tools/gen_reference_metrics.py``, and commit
both with the reason.  Fields no shipped scenario uses any more are removed.
Why the fields are shipped at all: :mod:`vesselbot_ros.vessels.cfd`
("Shipped fields").
"""

from __future__ import annotations

import sys

from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.cfd import field_file, network_field, shipped_field_dir
from vesselbot_ros.vessels.network import load_network


def shipped_networks() -> dict[str, tuple[object, object]]:
    """``{field file name: (network, blood)}`` of every shipped scenario that runs in a vessel network."""
    out: dict[str, tuple[object, object]] = {}
    for path in shipped_scenarios().values():
        phys = load_scenario(path).physics
        if phys.vessel.network:
            net = load_network(phys.vessel.network)
            out[field_file(net, phys.blood)] = (net, phys.blood)
    return out


def main() -> int:
    dest = shipped_field_dir()
    dest.mkdir(parents=True, exist_ok=True)
    wanted = shipped_networks()
    for name, (net, blood) in sorted(wanted.items()):
        field = network_field(net, blood, refresh=True)  # type: ignore[arg-type]
        field.save(dest / name)
        print(f"wrote {dest / name} ({field.nz} x {field.nx} grid, solved in {field.meta.get('total_s', 0.0):.1f} s)")
    for old in sorted(dest.glob("*.npz")):
        if old.name not in wanted:
            old.unlink()
            print(f"removed {old} (no shipped scenario uses it)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
