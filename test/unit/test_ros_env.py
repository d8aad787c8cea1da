"""ros_env: each run's own domain, localhost discovery, own logs, and our Fast DDS participant defaults."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

from vesselbot_ros import ros_env
from vesselbot_ros.ros_env import FASTDDS_PROFILE, FASTDDS_PROFILE_KEY, apply_to_process, restore_process_env, ros_environment

REPO = Path(__file__).resolve().parents[2]
KEY = "FASTRTPS_DEFAULT_PROFILES_FILE"  # what Fast DDS 2.x reads (restated: the test checks the constant)


def test_a_runs_environment_isolates_it_and_loads_our_participant_defaults(tmp_path: Path) -> None:
    env = ros_environment(42, tmp_path / "logs", base={"ROS_LOCALHOST_ONLY": "1", "PATH": "/bin"})
    assert env["ROS_DOMAIN_ID"] == "42" and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert "ROS_LOCALHOST_ONLY" not in env and env["ROS_LOG_DIR"] == str(tmp_path / "logs")
    assert (tmp_path / "logs").is_dir()
    assert FASTDDS_PROFILE_KEY == KEY and env[KEY] == str(FASTDDS_PROFILE)
    # a user's own profiles file is theirs to keep; an empty variable is no file
    assert ros_environment(42, tmp_path / "l2", base={KEY: "/etc/mine.xml"})[KEY] == "/etc/mine.xml"
    assert ros_environment(42, tmp_path / "l3", base={KEY: ""})[KEY] == str(FASTDDS_PROFILE)


def test_the_profile_is_valid_fast_dds_xml_announcing_every_quarter_second_and_ships_in_the_wheel() -> None:
    root = ET.parse(FASTDDS_PROFILE).getroot()
    ns = {"d": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    (part,) = root.findall("d:profiles/d:participant", ns)
    assert part.get("is_default_profile") == "true"
    lease = part.find("d:rtps/d:builtin/d:discovery_config/d:leaseAnnouncement", ns)
    assert lease is not None
    period = int(lease.findtext("d:sec", namespaces=ns)) + int(lease.findtext("d:nanosec", namespaces=ns)) * 1e-9
    assert period == 0.25
    # the lease itself (how long a silent peer is kept) stays Fast DDS's default, far above the announcement period
    assert part.find("d:rtps/d:builtin/d:discovery_config/d:leaseDuration", ns) is None
    assert FASTDDS_PROFILE.parent == Path(ros_env.__file__).parent
    assert f'"{FASTDDS_PROFILE.name}"' in (REPO / "setup.py").read_text()  # package data: installed with the module


def test_apply_to_process_sets_the_profile_for_an_in_process_context_and_restores_it(tmp_path: Path,
                                                                                    monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.delenv(KEY, raising=False)
    saved = apply_to_process(ros_environment(43, tmp_path))
    assert os.environ[KEY] == str(FASTDDS_PROFILE) and os.environ["ROS_DOMAIN_ID"] == "43"
    restore_process_env(saved)
    assert KEY not in os.environ
