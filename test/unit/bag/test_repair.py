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
    assert res.message_count == 300 * 8 + 3 + 3  # ticks, diagnostics, the three latched messages
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
    _bag, _ = write_synthetic_bag(live, 400, flush_every=100, finish=True)
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
    assert not res.repaired and res.message_count == 8013
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
    assert not list(headeronly.glob(".repair*"))


# -- never overwrite or delete an original recording (issue 14) --------------------------------------------------


def _digest(p):
    import hashlib

    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_renamed_bag_is_repaired_readable_under_its_files_names(tmp_path):
    killed = _killed_bag(tmp_path, 200, 0, 3000)
    renamed = tmp_path / "copy_of_run"
    shutil.copytree(killed, renamed)  # folder copy_of_run/, file run.mcap
    res = repair_bag(renamed)
    assert res.repaired and res.mcap_rewritten
    info = open_bag(renamed)
    assert info.consistent and [p.name for p in info.mcap_paths] == ["run.mcap"]
    assert sum(1 for _ in iter_messages(info)) == res.message_count


def test_second_forced_repair_never_overwrites_the_original(tmp_path):
    killed = _killed_bag(tmp_path, 200, 0, 3000)
    original = _digest(killed / "run.mcap")
    first = repair_bag(killed)
    assert first.damaged_path.name == "run.mcap.damaged" and _digest(first.damaged_path) == original
    # a first repair's output is intact: --force rebuilds metadata.yaml only and keeps the MCAP as it is
    repaired = _digest(killed / "run.mcap")
    second = repair_bag(killed, force=True)
    assert not second.mcap_rewritten and second.dropped_bytes == 0 and second.damaged_path is None
    assert _digest(killed / "run.mcap") == repaired
    assert _digest(killed / "run.mcap.damaged") == original
    # damage the repaired MCAP and repair again: the new original gets a new name, the first is untouched
    (killed / "run.mcap").write_bytes((killed / "run.mcap").read_bytes()[:-100])
    third = repair_bag(killed, force=True)
    assert third.mcap_rewritten and third.damaged_path.name == "run.mcap.damaged.2"
    assert _digest(killed / "run.mcap.damaged") == original
    assert {p.name for p in killed.iterdir()} >= {"metadata.yaml.orig", "metadata.yaml.orig.2"}
    assert open_bag(killed).consistent


def test_run_metadata_comes_from_the_mcap_without_the_side_file(synthetic_bag, tmp_path):
    bag = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], bag)
    (bag / RUN_METADATA_FILE).unlink()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")  # garbage
    res = repair_bag(bag)
    assert res.run_metadata_from == "mcap"
    assert open_bag(bag).run_metadata == RUN_METADATA


def test_garbage_metadata_with_an_intact_mcap_leaves_the_mcap_alone(synthetic_bag, tmp_path, capsys):
    from vesselbot_ros.cli import main

    bag = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], bag)
    mcap = _digest(bag / "run1.mcap")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 9\n   bad: [1\n")
    assert main(["bag", "info", str(bag)]) == 2
    err = capsys.readouterr().err.strip()
    assert "metadata.yaml" in err and "line 3 column" in err and "Mark" not in err and "0x" not in err
    assert main(["bag", "repair", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "the MCAP is intact (8013 messages)" in out and "trailing bytes" not in out
    assert "original kept as metadata.yaml.orig" in out
    assert _digest(bag / "run1.mcap") == mcap and not (bag / "run1.mcap.damaged").exists()
    assert open_bag(bag).consistent


def test_full_disk_during_repair_is_one_line_and_changes_nothing(tmp_path, monkeypatch, capsys):
    import errno

    from vesselbot_ros.bag import writer as bag_writer
    from vesselbot_ros.cli import main

    killed = _killed_bag(tmp_path, 200, 0, 3000)
    before = {p.name: _digest(p) for p in killed.iterdir()}
    real_write = bag_writer.JazzyMcapWriter.write
    calls = {"n": 0}

    def write(self, *a, **k):
        calls["n"] += 1
        if calls["n"] > 500:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(self, *a, **k)

    monkeypatch.setattr(bag_writer.JazzyMcapWriter, "write", write)
    assert main(["bag", "repair", str(killed)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "disk filled up while repairing" in err[0] and "nothing was changed" in err[0]
    assert {p.name: _digest(p) for p in killed.iterdir()} == before  # no .repair folder, nothing renamed


def test_too_little_free_space_is_refused_before_any_work(tmp_path, monkeypatch):
    import collections

    killed = _killed_bag(tmp_path, 50, 0)
    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 10**9, 1000))
    with pytest.raises(BagError, match=r"repair needs about \d+ MiB free, only 0 MiB left; nothing was changed"):
        repair_bag(killed)
    assert sorted(p.name for p in killed.iterdir()) == ["run.mcap", RUN_METADATA_FILE]
