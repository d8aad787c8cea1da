"""MCAP chunk compression (``--compression``): rosbag2's Jazzy storage presets, read by every reader."""

from __future__ import annotations

import pytest
from conftest import write_synthetic_bag

from vesselbot_ros.bag.reader import iter_messages, open_bag
from vesselbot_ros.bag.writer import COMPRESSION_PRESETS, BagWriter
from vesselbot_ros.errors import BagError

N_TICKS = 1500


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    out = {}
    for name in COMPRESSION_PRESETS:
        path = tmp_path_factory.mktemp("bags") / name
        _, sent = write_synthetic_bag(path, N_TICKS, compression=name)
        out[name] = (path, sent)
    return out


@pytest.mark.parametrize("name", ["zstd_fast", "zstd_small"])
def test_compressed_bag_is_indexed_consistent_and_decodes_equal_to_what_was_written(bags, name):
    path, sent = bags[name]
    info = open_bag(path)
    assert info.consistent, info.problems
    assert info.chunk_compression == "zstd"
    assert info.chunks >= 1
    assert info.message_count == len(sent)
    got = [(m.topic, m.decode()) for m in iter_messages(info)]
    assert len(got) == len(sent)
    by_topic: dict[str, list] = {}
    for t, msg in sent:
        by_topic.setdefault(t, []).append(msg)
    for t, msgs in by_topic.items():
        dec = [d for tt, d in got if tt == t]
        assert len(dec) == len(msgs)
        if t.endswith("/truth"):
            assert [(d.position.x, d.position.z) for d in dec] == [(m.position.x, m.position.z) for m in msgs]


def test_presets_chunk_and_compress_as_rosbag2_on_jazzy(bags):
    """zstd_small (4 MiB chunks, libzstd's strongest level) is much smaller than an uncompressed bag;
    zstd_fast (libzstd's fastest level, ZSTD_minCLevel) hardly compresses float payloads: within 2 %."""
    size = {n: (p / f"{p.name}.mcap").stat().st_size for n, (p, _) in bags.items()}
    assert size["zstd_small"] < 0.5 * size["none"]
    assert abs(size["zstd_fast"] / size["none"] - 1.0) < 0.02
    chunks = {n: open_bag(p).chunks for n, (p, _) in bags.items()}
    assert chunks["zstd_small"] < chunks["none"]  # 4 MiB against 1 MiB
    assert chunks["zstd_fast"] > chunks["none"]   # 768 KiB against 1 MiB
    assert open_bag(bags["none"][0]).chunk_compression == "none"


def test_metadata_yaml_reports_a_storage_preset_as_rosbag2_does(bags):
    """A storage preset compresses inside the MCAP: no file or message compression in metadata.yaml."""
    import yaml

    doc = yaml.safe_load((bags["zstd_small"][0] / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert doc["compression_format"] == "" and doc["compression_mode"] == ""
    assert doc["storage_identifier"] == "mcap"


def test_chunk_crc_only_where_the_preset_writes_it(bags):
    from mcap.reader import make_reader
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    for name, want_crc in (("zstd_fast", False), ("zstd_small", True), ("none", True)):
        path, _ = bags[name]
        with (path / f"{path.name}.mcap").open("rb") as fh:
            crcs = [r.uncompressed_crc for r in StreamReader(fh, skip_magic=False, emit_chunks=True).records if isinstance(r, Chunk)]
        assert crcs and all((c != 0) == want_crc for c in crcs), name
        with (path / f"{path.name}.mcap").open("rb") as fh:
            assert sum(1 for _ in make_reader(fh).iter_messages()) == len(bags[name][1])


@pytest.mark.parametrize("name", ["zstd_fast", "zstd_small"])
def test_foxglove_mcap_reader_decodes_every_message(bags, name):
    """Foxglove's MCAP reader (@mcap/core, through the index) and ROS 2 deserializer, run by node."""
    from vesselbot_ros.testing import run_node_script

    path, sent = bags[name]
    out = run_node_script("mcap_read.mjs", str(path / f"{path.name}.mcap"))
    assert out["chunk_compression"] == ["zstd"]
    assert out["decoded"] == len(sent)
    info = open_bag(path)
    assert out["counts"] == {t.name: t.count for t in info.topics if t.count}
    truth = [m for t, m in sent if t.endswith("/truth")]
    assert [(float(x), float(z)) for _, x, z in out["positions"]] == [(m.position.x, m.position.z) for m in truth]


def test_unknown_compression_is_a_clear_error(tmp_path):
    with pytest.raises(BagError, match="unknown compression 'gzip'; valid: none, zstd_fast, zstd_small"):
        BagWriter(tmp_path / "b", compression="gzip")
