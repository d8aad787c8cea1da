"""The graph settings (``graph.*``): defaults, and a bad value raises ConfigError naming it."""

from __future__ import annotations

import dataclasses

import pytest

from vesselbot_ros.config import ConfigError, load_dataclass
from vesselbot_ros.nodes.graph_params import GRAPH_PREFIX, GraphParams


def test_defaults_are_a_valid_lockstep_graph() -> None:
    g = GraphParams()
    assert g.mode == "lockstep" and g.real_time_factor == 1.0 and not g.autostart
    assert GRAPH_PREFIX == "graph."


@pytest.mark.parametrize(("field", "value"), [
    ("mode", "fast"), ("real_time_factor", 0.0), ("diagnostics_period_s", -1.0), ("stall_timeout_s", float("nan")),
    ("input_max_age_s", 0.0), ("future_tolerance_s", -1e-3), ("position_margin_m", -1.0),
])
def test_a_bad_value_is_refused_naming_its_field(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=field):
        dataclasses.replace(GraphParams(), **{field: value})


def test_loaded_from_parameter_values_strictly() -> None:
    assert load_dataclass(GraphParams, {"mode": "realtime", "real_time_factor": 0.5}, "graph").real_time_factor == 0.5
    with pytest.raises(ConfigError, match="unknown"):
        load_dataclass(GraphParams, {"no_such_setting": 1}, "graph")
