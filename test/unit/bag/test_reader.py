"""open_bag / iter_messages / read_timeseries: validation errors name the problem and the fix."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from vesselbot_ros.bag.reader import iter_messages, open_bag, read_timeseries
from vesselbot_ros.bag.synthetic import PARAMS
from vesselbot_ros.errors import BagError


@pytest.fixture
def bag_copy(synthetic_bag, tmp_path):
    dst = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], dst)
    return dst


def test_open_bag_describes_topics_times_run_and_consistency(synthetic_bag):
    info = open_bag(synthetic_bag[0])
    assert info.consistent and info.problems == ()
    assert info.topic("/vesselbot/truth").count == 1000 == info.topic("/vesselbot/truth").mcap_count
    assert info.topic("/diagnostics").count == 10
    assert info.topic("/vesselbot/vessel_markers").latched and not info.topic("/vesselbot/truth").latched
    assert info.run_metadata["seed"] == 7 and info.run_metadata["scenario"] == "synthetic"
    assert info.duration_ns == 999_000_000 + 7  # 1 ms ticks; +1 ns per message tied at tick 999 (8 topics)


def test_truncated_mcap_is_a_clear_error_pointing_to_repair(bag_copy):
    mcap = bag_copy / "run1.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=r"run1.mcap is truncated .* no MCAP footer.*vesselbot bag repair"):
        open_bag(bag_copy)


def test_bad_magic_missing_files_and_broken_metadata_are_clear_errors(bag_copy, tmp_path):
    mcap = bag_copy / "run1.mcap"
    data = bytearray(mcap.read_bytes())
    with pytest.raises(BagError, match="does not exist"):
        open_bag(tmp_path / "nope")
    meta = (bag_copy / "metadata.yaml").read_text()
    (bag_copy / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    with pytest.raises(BagError, match="metadata.yaml is corrupt"):
        open_bag(bag_copy)
    (bag_copy / "metadata.yaml").unlink()
    with pytest.raises(BagError, match="has no metadata.yaml; run `vesselbot bag repair"):
        open_bag(bag_copy)
    (bag_copy / "metadata.yaml").write_text(meta)
    mcap.write_bytes(b"GARBAGE!" + bytes(data[8:]))
    with pytest.raises(BagError, match="is not an MCAP file"):
        open_bag(bag_copy)
    mcap.unlink()
    with pytest.raises(BagError, match="run1.mcap listed in metadata.yaml is missing"):
        open_bag(bag_copy)


def test_corrupt_bytes_inside_a_chunk_are_a_clear_error_while_reading(bag_copy):
    mcap = bag_copy / "run1.mcap"
    data = bytearray(mcap.read_bytes())
    # overwrite the middle of the first chunk (messages) with 0xff: lengths become absurd
    data[5000:5400] = b"\xff" * 400
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagError, match="corrupt"):
        for _ in iter_messages(bag_copy):
            pass


def test_metadata_counts_that_disagree_with_the_mcap_are_reported(bag_copy):
    meta = bag_copy / "metadata.yaml"
    text = meta.read_text()
    import yaml

    doc = yaml.safe_load(text)
    for t in doc["rosbag2_bagfile_information"]["topics_with_message_count"]:
        if t["topic_metadata"]["name"] == "/vesselbot/truth":
            t["message_count"] = 999
    meta.write_text(yaml.safe_dump(doc))
    info = open_bag(bag_copy)
    assert not info.consistent
    assert "/vesselbot/truth: metadata.yaml says 999 messages, the MCAP holds 1000" in info.problems


def test_iter_messages_filters_topics_and_start_time(synthetic_bag):
    info = open_bag(synthetic_bag[0])
    msgs = list(iter_messages(info, topics=["/vesselbot/reference"], start_ns=info.start_ns + 500_000_000))
    assert [m.decode().tick for m in msgs] == list(range(500, 1000))
    with pytest.raises(BagError, match="has no topic /nope"):
        list(iter_messages(info, topics=["/nope"]))


def test_read_timeseries_matches_the_closed_form_stream(synthetic_bag):
    ts = read_timeseries(synthetic_bag[0])
    t = ts["truth.t_s"]
    np.testing.assert_allclose(t, np.arange(1000) * 1e-3, rtol=0, atol=1e-12)
    P = PARAMS
    np.testing.assert_allclose(ts["truth.p_WR"][:, 0], P["v_x"] * t + P["e0"] * np.exp(-t / P["tau"]),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(ts["estimate.p_hat"][:, 0] - ts["truth.p_WR"][:, 0], P["est_dx"], rtol=0, atol=1e-15)
    assert ts["coil.saturated"].dtype == bool
    assert ts["coil.saturated"].sum() == np.sum(np.abs(0.1 * np.sin(2 * np.pi * t)) > 0.08)
    assert ts["measurement.fresh"].all()  # every synthetic frame has a new stamp
    assert ts["truth.F_total"].shape == (1000, 3)


def test_final_diagnostics_keeps_the_last_status_of_every_name(synthetic_bag):
    from vesselbot_ros.bag.reader import final_diagnostics

    final = final_diagnostics(synthetic_bag[0])
    # the synthetic graph publishes a status every 100 ticks over 1000 ticks: the last is tick 900
    assert final == {"synthetic_graph": {"tick": "900"}}


def test_a_bag_from_before_3d_trees_reads_with_its_own_coil_state_and_no_y_slew_flag(tmp_path):
    """A planar bag recorded before CoilState carried slew_limited_y decodes with its embedded definition."""
    from rosbags.typesys import get_types_from_msg

    from vesselbot_ros.bag.writer import BagWriter, _msg_dirs, make_typestore
    from vesselbot_ros.graph_spec import topic

    name = "vesselbot_msgs/msg/CoilState"
    text = next(d / "CoilState.msg" for d in _msg_dirs("vesselbot_msgs") if (d / "CoilState.msg").is_file()).read_text()
    old_text = "\n".join(ln for ln in text.splitlines() if not ln.startswith("bool slew_limited_y"))
    assert old_text != text  # the installed definition has the field this bag's lacks
    ts = make_typestore()
    ts.fielddefs.pop(name)
    ts.register(get_types_from_msg(old_text, name))
    old = ts.types[name]
    hdr = ts.types["std_msgs/msg/Header"]
    stamp = ts.types["builtin_interfaces/msg/Time"]
    vec = ts.types["geometry_msgs/msg/Vector3"]
    with BagWriter(tmp_path / "old", typestore=ts) as bag:
        conn = bag.add_topic(topic("coil_state").name, name)
        for k in range(3):
            msg = old(header=hdr(stamp=stamp(sec=0, nanosec=k * 1_000_000), frame_id="vessel"), tick=k,
                      commanded=vec(x=0.1, y=0.0, z=-0.2), applied=vec(x=0.05 * k, y=0.0, z=-0.1),
                      saturation_scale=1.0, saturated=False, slew_limited_x=k == 1, slew_limited_z=k == 2,
                      command_rejected=False, watchdog_active=False, max_gradient=0.08, slew_rate=100.0,
                      dbdt_limit=0.0, dbdt_radius=0.0)
            bag.write(conn, ts.serialize_cdr(msg, name), 1_000 + k)
    out = read_timeseries(tmp_path / "old")
    assert out["coil.slew_limited_x"].tolist() == [False, True, False]
    assert out["coil.slew_limited_z"].tolist() == [False, False, True]
    assert out["coil.slew_limited_y"].tolist() == [False, False, False]
    assert out["coil.applied"][:, 0].tolist() == [0.0, 0.05, 0.1] and (out["coil.applied"][:, 1] == 0.0).all()


def test_a_bag_too_large_for_the_memory_is_refused_before_its_messages_are_read(synthetic_bag, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The series of a bag are held in memory: a bag the machine cannot hold (here: a 1 MiB budget for the
    synthetic bag's 8 thousand messages) is one line naming the bag, its messages and the estimate."""
    import re

    from vesselbot_ros.config import ConfigError

    info = open_bag(synthetic_bag[0])
    n = sum(t.count for t in info.topics if t.name != "/rosout")
    monkeypatch.setattr("vesselbot_ros.resources.memory_budget_bytes", lambda: 2**20)
    with pytest.raises(ConfigError, match=rf"^bag {re.escape(str(info.path))}=[0-9]+ messages: reading its time series needs about "
                                          r"[0-9.]+ MiB of memory, more than the 1\.0 MiB"):
        read_timeseries(info)
    assert n > 1000
