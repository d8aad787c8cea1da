"""``vesselbot vessels import FILE.vtp --out NAME.yaml``: a vessel network from a VMTK centreline file."""

from __future__ import annotations

import argparse
from pathlib import Path

from vesselbot_ros.atomic_io import check_output_file

__all__ = ["register", "run"]


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``import`` sub-command."""
    sub = parser.add_subparsers(dest="vessels_command", metavar="{import}", required=True)
    p = sub.add_parser("import", help="a network YAML from a VMTK centreline file (.vtp: vmtkcenterlines' raw "
                                      "paths or vmtkbranchextractor's branch-split form)")
    p.add_argument("file", help="the centreline file (.vtp, or legacy .vtk)")
    p.add_argument("--out", required=True, help="the network YAML to write (nothing is written on an error)")
    p.add_argument("--name", default=None, help="the network's name (default: the output file's stem)")
    p.add_argument("--unit-m", type=float, default=1.0e-3,
                   help="the file's length unit in metres (default 1e-3: mm); in it the radii must be a blood "
                        "vessel's, 1 um to 20 mm, and the tree span at most 1 m (vesselbot_ros.vessels.network: "
                        "MIN_RADIUS_M, MAX_RADIUS_M, MAX_LENGTH_M), else the file is refused (a network YAML too)")
    p.add_argument("--split-tolerance", type=float, default=0.5,
                   help="raw paths part where one leaves the tube of this fraction of the other's radius (0.5)")
    p.add_argument("--junction-factor", type=float, default=1.0,
                   help="a daughter's points closer to its node than this times the parent's end radius take the "
                        "daughter's radius just beyond (1.0; 0 keeps the file's radii)")
    p.add_argument("--radius-array", default="MaximumInscribedSphereRadius", help="point array of radii")


def run(args: argparse.Namespace) -> int:
    """Import, validate, write; print one line with what was written."""
    # deferred: the importer pulls in scipy/numba through the network module; `vesselbot vessels --help` imports this
    from vesselbot_ros.vessels.tree_io import import_vmtk_centerlines, write_network_yaml

    out = Path(args.out)
    check_output_file(out, "--out")  # before the import: a folder that cannot be written is one line, nothing read
    name = args.name or out.stem
    net = import_vmtk_centerlines(args.file, name=name, length_unit_m=args.unit_m,
                                  split_tolerance=args.split_tolerance, junction_factor=args.junction_factor,
                                  radius_array=args.radius_array)
    write_network_yaml(net, out, header=f"Imported from {Path(args.file).name} by `vesselbot vessels import` "
                                        f"(unit {args.unit_m!r} m, split tolerance {args.split_tolerance!r}, "
                                        f"junction factor {args.junction_factor!r}).\n"
                                        "Format: docs/vessels.md.")
    planar = "planar" if net.is_planar else "3-D"
    print(f"{out}: network {net.name!r}, {len(net.branches)} branches ({len(net.outlets)} outlets), {planar}")
    return 0
