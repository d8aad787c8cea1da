"""repair_bag: a hard-killed recorder's MCAP becomes a valid, complete bag up to its last chunk."""

from __future__ import annotations

import json
import shutil

import pytest

from conftest import RUN_METADATA, write_synthetic_bag
from vesselbot_ros.bag.reader import iter_messages, open_bag
from vesselbot_ros.bag.repair import repair_bag
from vesselbot_ros.bag.writer import RUN_METADATA_FILE
from vesselbot_ros.errors import BagError


def _killed_bag(tmp_path, flushed_ticks: int, unflushed_ticks: int, cut_extra: int = 0):
    """The files a SIGKILL would leave: everything flushed so far, nothing after, no metadata.yaml."""
    live = tmp_path / "live" / "run"
    bag, _ = write_synthetic_bag(live, flushed_ticks, flush_every=100, finish=False)
    bag.flush()
    killed = tmp_path / "killed" / "run"
    killed.mkdir(parents=True)
    data = bag.mcap_path.read_bytes()
    if cut_extra:  # a chunk half-written when the process died
        data = data + b"\x06" + (10**6).to_bytes(8, "little") + b"\0" * cut_extra
    (killed / "run.mcap").write_bytes(data)
    shutil.copy(live / RUN_METADATA_FILE, killed / RUN_METADATA_FILE)
    bag.finish()
    return killed


@pytest.mark.parametrize("cut_extra", [0, 5000])
def test_repair_rebuilds_a_valid_bag_with_every_flushed_message(tmp_path, cut_extra):
    killed = _killed_bag(tmp_path, 300, 0, cut_extra)
    with pytest.raises(BagError, match="no metadata.yaml; run `vesselbot bag repair"):
        open_bag(killed)
    res = repair_bag(killed)
    assert res.repaired
    assert res.counts["/vesselbot/truth"] == 300
    assert res.message_count == 300 * 8 + 3 + 2
    assert res.dropped_bytes == (0 if cut_extra == 0 else 1 + 8 + cut_extra)
    assert res.damaged_path.name == "run.mcap.damaged" and res.damaged_path.exists()
    info = open_bag(killed)
    assert info.consistent
    assert info.run_metadata == RUN_METADATA
    assert info.topic("/vesselbot/vessel_markers").latched
    ticks = [m.decode().tick for m in iter_messages(info, topics=["/vesselbot/truth"])]
    assert ticks == list(range(300))
    from rosbags.highlevel import AnyReader

    with AnyReader([killed]) as r:  # the repaired bag also reads with rosbags alone
        assert sum(1 for _ in r.messages()) == res.message_count
    meta = json.loads(info.path.joinpath(RUN_METADATA_FILE).read_text())
    assert meta["seed"] == 7


def test_repair_of_a_mcap_cut_inside_a_chunk_keeps_the_complete_chunks(tmp_path):
    live = tmp_path / "live" / "run"
    bag, _ = write_synthetic_bag(live, 400, flush_every=100, finish=True)
    data = (live / "run.mcap").read_bytes()
    killed = tmp_path / "k" / "run"
    killed.mkdir(parents=True)
    # cut in the middle of the file: somewhere inside the 2nd or 3rd of 4 chunks
    (killed / "run.mcap").write_bytes(data[: len(data) // 2])
    res = repair_bag(killed)
    n = res.counts["/vesselbot/truth"]
    assert n in (100, 200)
    ticks = [m.decode().tick for m in iter_messages(killed, topics=["/vesselbot/truth"])]
    assert ticks == list(range(n))


def test_repair_leaves_a_valid_bag_alone_and_rejects_non_mcap(synthetic_bag, tmp_path):
    res = repair_bag(synthetic_bag[0])
    assert not res.repaired and res.message_count == 8012
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "bad.mcap").write_bytes(b"not an mcap at all")
    with pytest.raises(BagError, match="not an MCAP file"):
        repair_bag(bad)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BagError, match="no .mcap file"):
        repair_bag(empty)
    headeronly = tmp_path / "h"
    headeronly.mkdir()
    (headeronly / "h.mcap").write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(BagError, match="holds no complete chunk"):
        repair_bag(headeronly)
    assert not (headeronly / ".repair").exists()
