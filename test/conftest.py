"""Shared fixtures: every ROS test gets its own domain id and log folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def ros(tmp_path):
    """An isolated rclpy Context on a leased domain (see vesselbot_ros.testing)."""
    from vesselbot_ros.testing import isolated_ros

    with isolated_ros(tmp_path) as sandbox:
        yield sandbox


@pytest.fixture
def peer_domain():
    """A domain id held for the test's own nodes until it ends; ``vesselbot run --domain-id`` joins it."""
    from vesselbot_ros.ros_env import allocate_domain_for_peers

    with allocate_domain_for_peers() as lease:
        yield lease.domain_id


@pytest.fixture
def repo() -> Path:
    """The repository root."""
    return REPO


def pytest_collection_modifyitems(config, items):  # type: ignore[no-untyped-def]
    """Tests marked ``slow`` first (stable): on two workers the longest ones start early instead of ending the run alone."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
