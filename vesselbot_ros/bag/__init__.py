"""vesselbot_ros.bag: the recorded bags (writer, reader, info, repair, replay, report).

A bag folder holds what rosbag2 writes (``metadata.yaml``, the ``.mcap`` files) and the recorder's
``run_metadata.json``, and nothing else, so that ``ros2 bag info`` and Foxglove see a clean bag.  What is
derived from a bag goes beside it, in ``<bag>.<what>/`` (:func:`derived_dir`): the report in ``<bag>.report/``,
``replay --into ROLE``'s result bag in ``<bag>.reestimate_<ROLE>/``, the node logs of ``vesselbot run`` in
``<bag>.logs/``; ``--out`` chooses another folder.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["derived_dir"]


def derived_dir(bag_dir: str | Path, what: str) -> Path:
    """The folder beside ``bag_dir`` for an output derived from it: ``<parent>/<bag name>.<what>``.

    ``runs/20261202T0916Z_sound_small_artery`` gives ``runs/20261202T0916Z_sound_small_artery.report`` for
    ``what="report"``.  A bag named ``.`` or ``..`` is resolved first (its folder has a name).
    """
    p = Path(bag_dir)
    if p.name in ("", ".", ".."):
        p = p.resolve()
    return p.with_name(f"{p.name}.{what}")
