"""Synthetic bags for the bag tests (closed-form contents, see vesselbot_ros.bag.synthetic)."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("rclpy")

RUN_METADATA = {
    "scenario": "synthetic",
    "seed": 7,
    "mode": "lockstep",
    "config": {"imager": {"outliers": [{"start_s": 0.5, "duration_s": 0.02, "magnitude_m": 1e-3}]}},
    "versions": {"vesselbot_ros": "test"},
    "command": ["vesselbot", "run", "--seed", "7"],
}


def write_synthetic_bag(path: Path, n_ticks: int, dt_s: float = 1e-3, flush_every: int = 0,
                        t0_ns: int = 1_700_000_000_000_000_000, finish: bool = True, compression: str = "none",
                        run_metadata: dict | None = None, edit=None):
    """Write ``n_ticks`` of the synthetic graph (1 ms apart in log time); return (writer, sent list).

    ``run_metadata`` replaces :data:`RUN_METADATA`; ``edit(k, topic name, message)``, if given, may change
    each tick's messages before they are written.
    """
    from rclpy.serialization import serialize_message

    from vesselbot_ros.bag.synthetic import latched_messages, tick_messages
    from vesselbot_ros.bag.writer import BagWriter
    from vesselbot_ros.graph_spec import TOPICS

    bag = BagWriter(path, run_metadata=RUN_METADATA if run_metadata is None else run_metadata,
                    compression=compression).open()
    conns = {s.name: bag.add_topic(s.name, s.msgtype, latched=s.qos == "reliable_latched", depth=s.depth)
             for s in TOPICS}
    sent = []
    t_ns = t0_ns
    for name, msg in latched_messages():
        bag.write(conns[name], serialize_message(msg), t_ns)
        sent.append((name, msg))
    for k in range(n_ticks):
        t_ns = t0_ns + int(round(k * dt_s * 1e9))
        for name, msg in tick_messages(k, dt_s):
            if edit is not None:
                edit(k, name, msg)
            bag.write(conns[name], serialize_message(msg), t_ns)
            sent.append((name, msg))
        if flush_every and (k + 1) % flush_every == 0:
            bag.flush()
    if finish:
        bag.finish()
    return bag, sent


@pytest.fixture(scope="module")
def synthetic_bag(tmp_path_factory):
    """A finished bag of 1000 ticks (1 s at 1 kHz) and the messages written, in order."""
    path = tmp_path_factory.mktemp("bags") / "run1"
    _, sent = write_synthetic_bag(path, 1000)
    return path, sent
