"""BagWriter: rosbag2 v9 + MCAP round trips through rosbags and mcap, custom types from embedded definitions."""

from __future__ import annotations

import json

import pytest
import yaml
from conftest import RUN_METADATA, write_synthetic_bag

from vesselbot_ros.bag.writer import RUN_METADATA_FILE, RUN_METADATA_KEY, BagWriter, check_output_dir
from vesselbot_ros.errors import BagError
from vesselbot_ros.graph_spec import frame_topics, topic

CUSTOM = {"vesselbot_msgs/msg/PlantState", "vesselbot_msgs/msg/ReferenceSample", "vesselbot_msgs/msg/CoilState"}


def test_metadata_yaml_is_version_9_mcap_with_counts_qos_and_run_metadata(synthetic_bag):
    path, sent = synthetic_bag
    info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["run1.mcap"]
    expected = {}
    for name, _ in sent:
        expected[name] = expected.get(name, 0) + 1
    got = {t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]}
    # every topic sent, with its count (the synthetic run sends the continuous scanner phase once); every other
    # topic of the graph spec is declared with no message (a run without a stall has no coil/stall; a run whose
    # imager delivers positions has no MR frames)
    assert {k: n for k, n in got.items() if n} == expected
    assert {k: n for k, n in got.items() if not n} == {topic(k).name: 0 for k in ("coil_stall", *frame_topics())}
    assert expected[topic("sequence_phase").name] == 1
    assert info["message_count"] == len(sent) == 8 * 1000 + 10 + 3
    durab = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"][0]["durability"]
             for t in info["topics_with_message_count"]}
    assert durab["/vesselbot/vessel_markers"] == "transient_local"
    assert durab["/vesselbot/truth"] == "volatile"
    assert json.loads(info["custom_data"][RUN_METADATA_KEY]) == RUN_METADATA
    assert json.loads((path / RUN_METADATA_FILE).read_text()) == RUN_METADATA
    # starting time and duration in integer ns: ticks are 1 ms apart, 1000 ticks
    assert info["starting_time"]["nanoseconds_since_epoch"] == 1_700_000_000_000_000_000
    assert 999_000_000 <= info["duration"]["nanoseconds"] <= 999_000_000 + 20


def assert_same(decoded, sent, where="msg"):
    """Field-by-field equality of a decoded message (rosbags / mcap_ros2 object) and the rclpy message sent."""
    if hasattr(sent, "get_fields_and_field_types"):
        for name in sent.get_fields_and_field_types():
            assert_same(getattr(decoded, name), getattr(sent, name), f"{where}.{name}")
    elif isinstance(sent, bytes) and len(sent) == 1 and isinstance(decoded, int):
        assert decoded == sent[0], where  # rclpy's `byte` is bytes, the decoders give an int
    elif isinstance(sent, (str, bytes, int, float, bool)):
        assert decoded == sent, where
    else:  # sequences / arrays (rclpy array.array, numpy, list)
        d, s_ = list(decoded), list(sent)
        assert len(d) == len(s_), where
        for i, (a, b) in enumerate(zip(d, s_)):
            assert_same(a, b, f"{where}[{i}]")


def test_anyreader_decodes_every_message_equal_to_what_was_written(synthetic_bag):
    from rosbags.highlevel import AnyReader

    path, sent = synthetic_bag
    with AnyReader([path]) as reader:  # no typestore passed: definitions come from the bag
        got = [(c.topic, reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()]
    assert [n for n, _ in got] == [n for n, _ in sent]
    for (n, a), (_, b) in zip(got, sent):
        assert_same(a, b, n)
    truth = [m for n, m in got if n == "/vesselbot/truth"]
    assert [m.tick for m in truth] == list(range(1000))
    assert truth[3].forces.steric.x == pytest.approx(7e-9, rel=1e-12)  # term 7 of eq. (1): 7 nN


def test_mcap_ros2_decodes_custom_types_from_the_embedded_schemas_alone(synthetic_bag):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    path, sent = synthetic_bag
    seen: dict[str, int] = {}
    with (path / "run1.mcap").open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert {s.encoding for s in schemas.values()} == {"ros2msg"}
        assert "MSG: vesselbot_msgs/ForceBreakdown" in schemas["vesselbot_msgs/msg/PlantState"].data.decode()
        assert reader.get_header().profile == "ros2"
        decoded = list(reader.iter_decoded_messages(log_time_order=True))
    for schema, channel, _message, _ros in decoded:
        seen[schema.name] = seen.get(schema.name, 0) + 1
        assert channel.message_encoding == "cdr"
        assert "offered_qos_profiles" in channel.metadata
    assert CUSTOM <= set(seen)
    coil = [r for s, _, _, r in decoded if s.name == "vesselbot_msgs/msg/CoilState"]
    sent_coil = [m for n, m in sent if n == "/vesselbot/coil/state"]
    assert len(coil) == len(sent_coil) == 1000
    for a, b in zip(coil, sent_coil):
        assert_same(a, b, "coil")
    truth = [r for s, _, _, r in decoded if s.name == "vesselbot_msgs/msg/PlantState"]
    for a, b in zip(truth, [m for n, m in sent if n == "/vesselbot/truth"]):
        assert_same(a, b, "truth")


def test_log_times_are_strictly_increasing_even_for_equal_receive_times(tmp_path):
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    with BagWriter(tmp_path / "b") as bag:
        c = bag.add_topic("/x", "std_msgs/msg/String")
        used = [bag.write(c, serialize_message(String(data=str(i))), 1000) for i in range(5)]
        used.append(bag.write(c, serialize_message(String(data="late")), 500))
    assert used == [1000, 1001, 1002, 1003, 1004, 1005]


def test_existing_directory_with_logs_is_accepted_but_an_existing_bag_is_never_overwritten(tmp_path):
    out = tmp_path / "run"
    (out / "logs").mkdir(parents=True)
    with BagWriter(out) as bag:
        bag.add_topic("/x", "std_msgs/msg/String")
    assert (out / "metadata.yaml").is_file() and (out / "logs").is_dir()
    with pytest.raises(BagError, match=r"already holds a bag \(metadata.yaml, run.mcap\)"):
        check_output_dir(out)
    with pytest.raises(BagError, match="metadata.yaml exists already"):
        BagWriter(out).open()


def test_finish_is_idempotent_and_writing_after_it_is_an_error(tmp_path):
    bag = BagWriter(tmp_path / "b").open()
    c = bag.add_topic("/x", "std_msgs/msg/String")
    bag.finish()
    bag.finish()
    with pytest.raises(BagError, match="is not open"):
        bag.write(c, b"\0\1\0\0\0\0\0\0", 1)
    with pytest.raises(BagError, match="already finished"):
        bag.open()


def test_unwritable_or_full_output_directories_fail_before_recording(tmp_path):
    afile = tmp_path / "a_file"
    afile.write_text("x")
    with pytest.raises(BagError, match=r"cannot create bag directory .*a_file/run"):
        check_output_dir(afile / "run")
    with pytest.raises(BagError, match=r"MiB free under .*; recording to .*ok needs at least .*; nothing was created"):
        check_output_dir(tmp_path / "ok", min_free_bytes=2**62)
    assert not (tmp_path / "ok").exists()


def test_the_write_probe_never_stays_and_a_refused_folder_is_removed(tmp_path):
    """On a full disk (a child whose files cannot grow: RLIMIT_FSIZE = 0) the probe's write fails: the probe file,
    and the folders the check made, are gone; a folder that was there stays, empty."""
    import subprocess
    import sys
    import textwrap

    made, kept = tmp_path / "runs" / "run1", tmp_path / "kept"
    kept.mkdir()
    code = textwrap.dedent(f"""
        import resource
        resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))
        from vesselbot_ros.bag.writer import check_output_dir
        from vesselbot_ros.errors import BagError
        for path in ({str(made)!r}, {str(kept)!r}):
            try:
                check_output_dir(path)
            except BagError as exc:
                print(exc)
    """)
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert child.returncode == 0, child.stderr
    assert child.stdout.splitlines() == [f"bag directory {made} is not writable: File too large",
                                         f"bag directory {kept} is not writable: File too large"]
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["kept"]  # no .write_probe_NNN, no runs/run1


def test_unknown_types_and_duplicate_topics_are_clear_errors(tmp_path):
    with BagWriter(tmp_path / "b") as bag:
        bag.add_topic("/x", "std_msgs/msg/String")
        with pytest.raises(BagError, match="already added"):
            bag.add_topic("/x", "std_msgs/msg/String")
        with pytest.raises(BagError, match="unknown message type 'nopkg/msg/Nothing'"):
            bag.add_topic("/y", "nopkg/msg/Nothing")
    with pytest.raises(BagError, match="not JSON-serialisable"):
        BagWriter(tmp_path / "c", run_metadata={"x": object()})


def test_flush_closes_the_chunk_so_a_copy_taken_now_holds_every_message(tmp_path):
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    bag, _ = write_synthetic_bag(tmp_path / "b", 50, finish=False)
    assert bag.pending_bytes() > 0
    bag.flush()
    assert bag.pending_bytes() == 0
    data = bag.mcap_path.read_bytes()  # what a hard kill would leave on disk
    n = 0
    from io import BytesIO

    try:
        for rec in StreamReader(BytesIO(data)).records:
            n += isinstance(rec, Message)
    except Exception:  # noqa: BLE001 - no footer: the stream ends abruptly
        pass
    assert n == 50 * 8 + 1 + 3  # ticks, diagnostics, the three latched messages
    bag.finish()


def test_bag_is_what_ros2_bag_record_writes_on_jazzy(synthetic_bag):
    """rosbag2 Jazzy (mcap_storage.cpp, qos.cpp) and mcap's writer defaults, field by field."""
    from binascii import crc32

    from mcap.reader import make_reader
    from mcap.records import Footer
    from mcap.stream_reader import StreamReader

    path, _ = synthetic_bag
    info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["ros_distro"] == "jazzy"
    for t in info["topics_with_message_count"]:
        tm = t["topic_metadata"]
        assert tm["type_description_hash"].startswith("RIHS01_")
        for q in tm["offered_qos_profiles"]:
            for key in ("deadline", "lifespan", "liveliness_lease_duration"):
                assert q[key] == {"sec": 9223372036, "nsec": 854775807}, (tm["name"], key)
    mcap = path / "run1.mcap"
    hashes = {t["topic_metadata"]["name"]: t["topic_metadata"]["type_description_hash"]
              for t in info["topics_with_message_count"]}
    with mcap.open("rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        for ch in summary.channels.values():
            assert ch.metadata["topic_type_hash"] == hashes[ch.topic]
            assert "offered_qos_profiles" in ch.metadata
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert "ros_distro: jazzy" in meta["rosbag2"]["serialized_metadata"]
        assert sum(1 for _ in reader.iter_messages()) == info["message_count"]  # every chunk CRC checked
    data = mcap.read_bytes()
    from mcap.records import Chunk

    records = list(StreamReader(str(mcap), emit_chunks=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert chunks and all(c.uncompressed_crc == crc32(c.data) != 0 for c in chunks)
    footer = next(r for r in records if isinstance(r, Footer))
    assert footer.summary_crc != 0
    assert footer.summary_crc == crc32(data[footer.summary_start:len(data) - 8 - 4])
    # a bag read from the MCAP alone keeps its type hashes (rosbags reads the channel metadata)
    from vesselbot_ros.bag.reader import open_bag

    assert open_bag(path).consistent
