"""Compatibility alias of :mod:`vesselbot_ros.graph_spec` (the graph spec: roles, topics, services).

New code imports :mod:`vesselbot_ros.graph_spec`; this module re-exports its
names for code written against the old topic table.
"""

from __future__ import annotations

from vesselbot_ros.graph_spec import (
    FRAME_ID,
    NODE_NAMES,
    SERVICES,
    TOPICS,
    ServiceSpec,
    TopicSpec,
    markdown_table,
    qos_profile,
    service,
    topic,
)

__all__ = ["TopicSpec", "ServiceSpec", "TOPICS", "SERVICES", "FRAME_ID", "NODE_NAMES", "topic", "service",
           "qos_profile", "markdown_table"]
