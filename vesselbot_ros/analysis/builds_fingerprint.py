"""Bit-level fingerprints of what is built once per machine: the plans, the 3-D wall field, the generated tree.

:mod:`vesselbot_ros.sim.fingerprint` fingerprints the per-run loop; this
module fingerprints the artefacts a machine makes once and then reads: the
planner's plans of the shipped scanner presets (``config/plans``, rebuilt by
``vesselbot plan``), the 3-D plant's wall field (built from a shipped tree's
wall into the per-machine cache, :func:`~vesselbot_ros.vessels.tree_field.wall_arrays`),
and the synthetic tree's generator and importer (``tools/make_synthetic_tree_3d.py``,
``vesselbot vessels import``).  The cross-kernel test
(``test/unit/analysis/test_builds_fingerprint.py``) runs
``python -m vesselbot_ros.analysis.builds_fingerprint --with-cores`` under each
OpenBLAS kernel the CPU supports and compares the lines.

Nothing here reads or writes a cache: the wall is built by
:func:`~vesselbot_ros.geometry.field_build.build_wall_field3d` itself, at the
plant's settings, on a block of the shipped carotid tree's grid round its
bifurcation, with the candidate tree's roots round the block only (the full
build takes 40-170 s a tree: the same code on every cell and every root, so a
block that holds model cells of one to three models, list cells and refined
cells exercises all of it).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import importlib.util
import io
import json
import sys
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PLAN_PRESETS", "WALL_BLOCK", "fingerprint_plans", "fingerprint_wall_block", "fingerprint_tree_generator",
           "fingerprint_builds"]

#: The scanner presets whose plans are shipped (``config/plans/<preset>.yaml``, tools/gen_plan_study.py).
PLAN_PRESETS = ("clinical_3t", "clinical_3t_mfde", "propulsion_insert")
#: The wall block: (network, lowest node (i, j, k) of the block in the plant's grid, nodes per axis).  The smallest
#: of the blocks tried that holds every kind of cell the full build makes (model cells of one, two and three
#: walls, list cells, refined blocks, exact cells; test_builds_fingerprint checks it): 17 nodes a side, 0.6 of
#: the 25-node block's build time it replaced.
WALL_BLOCK = ("carotid_bifurcation_3d", (176, 16, 36), (17, 17, 17))
#: The exact wall's candidate tree is built over the block plus this margin (m) only (its roots there are the whole
#: tree's; the ball rule's balls, at most the lumen's 9 mm across, stay in it): a third of the carotid's roots.
TREE_MARGIN_M = 10e-3

_ROOT = Path(__file__).resolve().parents[2]


def _sha(*parts: bytes) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(len(p).to_bytes(8, "little"))
        h.update(p)
    return h.hexdigest()


def fingerprint_plans(presets: Iterable[str] = PLAN_PRESETS) -> dict[str, str]:
    """``{"plan/<preset>": sha}`` of ``make_plan`` on ``clinical_3t_small_artery`` with each preset (as
    tools/gen_plan_study.py plans it): the whole plan (reference, segments, margins), ``repr`` of every float."""
    # deferred: the planner, the 3-D wall and the tree importer (vtk) are heavy; each part loads only its own
    from vesselbot_ros.analysis.plan import make_plan
    from vesselbot_ros.analysis.scanner_study import preset_changes
    from vesselbot_ros.sim.scenario import load_scenario

    out = {}
    for preset in presets:
        base = load_scenario("clinical_3t_small_artery", sets=[f"{k}={v}" for k, v in preset_changes(preset).items()])
        out[f"plan/{preset}"] = _sha(repr(make_plan(base)).encode())
    return out


def fingerprint_wall_block(block: tuple[str, tuple[int, int, int], tuple[int, int, int]] = WALL_BLOCK) -> dict[str, str]:
    """``{"wall/<network>/<array>": sha}`` of the wall field's arrays built at the plant's settings on ``block`` of
    the shipped tree's grid, and of the exact wall's own arrays (its triangles' data, patches, candidate tree over
    the block and :data:`TREE_MARGIN_M` round it)."""
    # deferred: as above
    from vesselbot_ros.vessels import tree_field as pf
    from vesselbot_ros.vessels.network import load_network

    name, lo, shape = block
    fld = pf.plant_field(load_network(name))  # the shipped samples (config/cfd), never the machine's cache
    origin = np.asarray(fld.origin, dtype=np.float64) + fld.h * np.asarray(lo, dtype=np.float64)
    top = origin + fld.h * (np.asarray(shape, dtype=np.float64) - 1.0)
    wall = fld.block_wall((origin - TREE_MARGIN_M, top + TREE_MARGIN_M))
    wf = pf.build_plant_field(wall, fld.h, origin, shape)
    names = ("head", "field", "fine", "d", "pbox", "pstart", "grid", "nodes", "index")
    out = {f"wall/{name}/{n}": _sha(np.ascontiguousarray(a).tobytes()) for n, a in zip(names, wf.args, strict=True)}
    out[f"wall/{name}/surface"] = _sha(*(np.ascontiguousarray(a).tobytes() for a in wall._args))
    # what the block holds (not a fingerprint: a block without model, list or refined cells would test less)
    out[f"wall/{name}/cells"] = " ".join(f"{k}={wf.stats[k]:g}" for k in ("model_cells_1", "model_cells_2", "model_cells_3",
                                                                          "list_cells", "refined_blocks", "exact_cells"))
    return out


def fingerprint_tree_generator(root: Path = _ROOT) -> dict[str, str]:
    """``{"tree/...": sha}`` of the files tools/make_synthetic_tree_3d.py writes (into a temporary folder) and of
    the network ``vesselbot vessels import`` makes of the shipped VTK file; ``{}`` outside a source checkout."""
    tool = root / "tools" / "make_synthetic_tree_3d.py"
    if not tool.is_file():
        return {}
    from vesselbot_ros.vessels.tree_io import import_vmtk_centerlines  # deferred: as above

    spec = importlib.util.spec_from_file_location("_make_synthetic_tree_3d", tool)
    assert spec is not None and spec.loader is not None
    mod: Any = importlib.util.module_from_spec(spec)  # the tool's globals are set below
    spec.loader.exec_module(mod)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        mod.VTP, mod.YAML, mod.ROOT = Path(tmp) / "t.vtp", Path(tmp) / "t.yaml", Path(tmp)
        with contextlib.redirect_stdout(io.StringIO()):  # its one line of progress: stdout is the JSON
            mod.main()
        out["tree/generated.vtp"] = _sha(mod.VTP.read_bytes())
        out["tree/generated.yaml"] = _sha(mod.YAML.read_bytes())
    shipped = root / "config" / "vessels" / "sources" / "synthetic_tree_3d.vtp"
    out["tree/imported"] = _sha(repr(import_vmtk_centerlines(shipped, name="synthetic_tree_3d")).encode())
    return out


def fingerprint_builds(parts: Iterable[str] = ("plans", "wall", "tree")) -> dict[str, str]:
    """The fingerprints of ``parts`` (``plans``, ``wall``, ``tree``)."""
    makers: dict[str, Callable[[], dict[str, str]]] = {"plans": fingerprint_plans, "wall": fingerprint_wall_block,
                                                       "tree": fingerprint_tree_generator}
    out: dict[str, str] = {}
    for part in parts:
        out.update(makers[part]())
    return out


def main(argv: list[str] | None = None) -> int:
    """Print the fingerprints as JSON on stdout."""
    from vesselbot_ros.sim.fingerprint import openblas_cores  # deferred: it loads the closed loop, which only --with-cores needs

    ap = argparse.ArgumentParser(prog="python -m vesselbot_ros.analysis.builds_fingerprint", description=__doc__)
    ap.add_argument("--part", action="append", choices=("plans", "wall", "tree"), help="what to build (default: all)")
    ap.add_argument("--with-cores", action="store_true", help="also report the OpenBLAS cores in use (key '_openblas')")
    args = ap.parse_args(argv)
    out: dict[str, Any] = fingerprint_builds(args.part or ("plans", "wall", "tree"))
    if args.with_cores:
        out["_openblas"] = openblas_cores()
    json.dump(out, sys.stdout, indent=1, sort_keys=True)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
