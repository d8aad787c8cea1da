#!/usr/bin/env python3
"""Solve the flow of every shipped scenario's vessel network afresh and ship the sampled fields in config/cfd/.

Planar networks ship their 2-D fields (:mod:`vesselbot_ros.vessels.cfd`); 3-D trees ship the 3-D plant's samples
(``<tree>-<key>.3d.npz``: :mod:`vesselbot_ros.vessels.tree_field`).

Run it (``.venv/bin/python tools/ship_cfd_fields.py``) after a change of a shipped
network, of the CFD settings or code (``cfd.CACHE_VERSION``) or of a shipped
scenario's blood model, then ``tools/gen_reference_metrics.py``, and commit
both with the reason.  ``--only-3d`` makes the 3-D trees' samples alone (after a change of
:mod:`vesselbot_ros.vessels.tree_field`'s ``FIELD3D_VERSION``: the 3-D flow solves are read from the
cache when there, the planar fields are left as they are).  Fields no shipped scenario uses any more are removed.
Why the fields are shipped at all: :mod:`vesselbot_ros.vessels.cfd`
("Shipped fields").
"""

from __future__ import annotations

import argparse
import sys

from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.cfd import field_file, network_field, shipped_field_dir
from vesselbot_ros.vessels.network import load_network
from vesselbot_ros.vessels.tree_field import field_key, plant_field


def shipped_networks(three_d: bool = False) -> dict[str, tuple[object, object]]:
    """``{field file name: (network, blood)}`` of every shipped scenario that runs in a planar vessel network
    (``three_d``: in a 3-D tree, its samples' file name)."""
    out: dict[str, tuple[object, object]] = {}
    for path in shipped_scenarios().values():
        phys = load_scenario(path).physics
        if phys.vessel.network:
            net = load_network(phys.vessel.network)
            if net.is_3d and three_d:
                out[f"{net.name}-{field_key(net, phys.blood)}.3d.npz"] = (net, phys.blood)
            elif not net.is_3d and not three_d:
                out[field_file(net, phys.blood)] = (net, phys.blood)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only-3d", action="store_true", help="make the 3-D trees' samples alone")
    args = ap.parse_args()
    dest = shipped_field_dir()
    dest.mkdir(parents=True, exist_ok=True)
    wanted = shipped_networks()
    for name, (net, blood) in sorted(wanted.items()):
        if args.only_3d:
            continue
        field = network_field(net, blood, refresh=True)  # type: ignore[arg-type]
        field.save(dest / name)
        print(f"wrote {dest / name} ({field.nz} x {field.nx} grid, solved in {field.meta.get('total_s', 0.0):.1f} s)")
    wanted_3d = shipped_networks(three_d=True)
    for name, (net, blood) in sorted(wanted_3d.items()):
        fld = plant_field(net, blood, refresh=True)  # type: ignore[arg-type]
        fld.save(dest / name)
        print(f"wrote {dest / name} ({fld.shape} grid, {len(fld.triangles)} wall triangles, "
              f"{(dest / name).stat().st_size / 1e6:.1f} MB)")
    for old in sorted(dest.glob("*.npz")):
        if old.name not in wanted and old.name not in wanted_3d:
            old.unlink()
            print(f"removed {old} (no shipped scenario uses it)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
