"""The strict loader: unknown keys, wrong types, range checks, nesting, round trip."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import pytest

from vesselbot_ros.config import (
    MAX_CONFIG_BYTES,
    ConfigError,
    apply_overrides,
    check_positive,
    check_range,
    flatten,
    load_dataclass,
    load_yaml,
    parse_set_items,
    to_mapping,
    unflatten,
)


@dataclass(frozen=True)
class Inner:
    radius_m: float = 2.5e-4
    ratio: float = 0.15

    def __post_init__(self) -> None:
        check_positive("radius_m", self.radius_m)
        check_range("ratio", self.ratio, 0.0, 1.0, hi_open=True)


@dataclass(frozen=True)
class Outer:
    name: str = "x"
    count: int = 3
    mode: Literal["a", "b"] = "a"
    anchors: tuple[tuple[float, float], ...] = ((0.0, 1.0),)
    inner: Inner = field(default_factory=Inner)


def test_defaults_and_coercion():
    cfg = load_dataclass(Outer, {"count": 4.0, "inner": {"radius_m": 1}, "anchors": [[0, 1], [2, 3.5]]})
    assert cfg.count == 4 and isinstance(cfg.count, int)
    assert cfg.inner.radius_m == 1.0 and isinstance(cfg.inner.radius_m, float)
    assert cfg.anchors == ((0.0, 1.0), (2.0, 3.5))


def test_unknown_key_names_the_dotted_path_and_value():
    with pytest.raises(ConfigError, match=r"unknown key inner\.radius \(value 3\)"):
        load_dataclass(Outer, {"inner": {"radius": 3}})


def test_wrong_type_names_the_key():
    with pytest.raises(ConfigError, match=r"inner\.radius_m must be a number, got 'big'"):
        load_dataclass(Outer, {"inner": {"radius_m": "big"}})
    with pytest.raises(ConfigError, match=r"count must be an integer, got 2\.5"):
        load_dataclass(Outer, {"count": 2.5})
    with pytest.raises(ConfigError, match=r"mode must be one of \['a', 'b'\], got 'c'"):
        load_dataclass(Outer, {"mode": "c"})


def test_range_errors_are_prefixed_with_the_section():
    with pytest.raises(ConfigError, match=r"inner\.radius_m must be > 0, got -0\.00025"):
        load_dataclass(Outer, {"inner": {"radius_m": -2.5e-4}})
    with pytest.raises(ConfigError, match=r"inner\.ratio must be in \[0\.0, 1\.0\), got 1\.0"):
        load_dataclass(Outer, {"inner": {"ratio": 1.0}})
    with pytest.raises(ConfigError, match=r"inner\.radius_m must be finite, got nan"):
        load_dataclass(Outer, {"inner": {"radius_m": float("nan")}})


def test_round_trip_through_mapping_and_flat_parameters():
    cfg = load_dataclass(Outer, {"name": "y", "inner": {"ratio": 0.3}})
    mapping = to_mapping(cfg)
    assert load_dataclass(Outer, mapping) == cfg
    flat = flatten(mapping)
    assert flat["inner.ratio"] == 0.3
    assert load_dataclass(Outer, unflatten(flat)) == cfg


def test_load_yaml_errors(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_yaml(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\n")
    with pytest.raises(ConfigError, match="is not valid YAML"):
        load_yaml(bad)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("3\n")
    with pytest.raises(ConfigError, match="must hold a mapping"):
        load_yaml(scalar)


def test_yaml_exponent_floats_without_a_dot_are_numbers(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("a: 1e-6\nb: 1.72e6\nc: 3\nd: -2E+3\ne: text1e5\n")
    data = load_yaml(f)
    assert data == {"a": 1e-6, "b": 1.72e6, "c": 3, "d": -2000.0, "e": "text1e5"}
    assert isinstance(data["c"], int)


# -- what is not a configuration is refused with one line (issue 14) ---------------------------------------------


def _file(tmp_path, content, name="c.yaml"):
    f = tmp_path / name
    if isinstance(content, bytes):
        f.write_bytes(content)
    else:
        f.write_text(content)
    return f


@pytest.mark.parametrize("content", ["", "\n# only a comment\n", "---\n", "{}\n"])
def test_empty_file_is_refused(tmp_path, content):
    with pytest.raises(ConfigError, match=r"c\.yaml' is empty"):
        load_yaml(_file(tmp_path, content))


def test_binary_file_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"is not UTF-8 text \(byte 0\)"):
        load_yaml(_file(tmp_path, b"\x89\xff\xfe\x00PNG\x00\x01"))
    with pytest.raises(ConfigError, match=r"not a text file"):
        load_yaml(_file(tmp_path, b"a: 1\n\x00\x01\x02"))


@pytest.mark.parametrize("text", ["a: " + "[" * 5000 + "]" * 5000, "a:\n" + "".join(" " * i + "- \n" for i in range(200))])
def test_deeply_nested_file_is_refused_before_recursion(tmp_path, text):
    with pytest.raises(ConfigError, match=r"nesting deeper than 32 levels at line \d+ column \d+"):
        load_yaml(_file(tmp_path, text))


def test_huge_file_is_refused_without_reading_it(tmp_path):
    f = tmp_path / "big.yaml"
    with f.open("w") as fh:
        fh.write("a: '")
        fh.seek(MAX_CONFIG_BYTES + 10)
        fh.write("'\n")
    with pytest.raises(ConfigError, match=r"big\.yaml' is \d+ bytes; a configuration is at most"):
        load_yaml(f)


def test_self_expanding_yaml_is_refused(tmp_path):
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    for i in range(1, 10):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]")
    with pytest.raises(ConfigError, match="aliases are expanded"):
        load_yaml(_file(tmp_path, "\n".join(lines) + "\n"))
    with pytest.raises(ConfigError, match="recursive alias at line 1"):
        load_yaml(_file(tmp_path, "a: &x [1, *x]\n"))
    # a few aliases are fine
    assert load_yaml(_file(tmp_path, "a: &v [1, 2]\nb: *v\n")) == {"a": [1, 2], "b": [1, 2]}


def test_duplicate_key_names_the_key_and_both_lines(tmp_path):
    with pytest.raises(ConfigError, match=r"duplicate key 'sim' at line 1 and line 4"):
        load_yaml(_file(tmp_path, "sim:\n  duration_s: 1\nname: x\nsim:\n  duration_s: 2\n"))
    with pytest.raises(ConfigError, match=r"duplicate key 'duration_s' at line 2 and line 3"):
        load_yaml(_file(tmp_path, "sim:\n  duration_s: 1\n  duration_s: 2\n"))


def test_invalid_yaml_names_line_and_column_not_a_python_repr(tmp_path):
    with pytest.raises(ConfigError) as info:
        load_yaml(_file(tmp_path, "a: 1\nb: [1, 2\nc: 3\n"))
    msg = str(info.value)
    assert "line " in msg and "column " in msg and "Mark" not in msg and "0x" not in msg


def test_yaml_text_bounds_apply_to_set_values():
    with pytest.raises(ConfigError, match="--set a is not valid YAML: duplicate key 'k'"):
        parse_set_items(["a={k: 1, k: 2}"])
    assert parse_set_items(["imager.noise_sigma_m=1e-4", "x.y= [1, 2e3]"]) == {
        "imager.noise_sigma_m": 1e-4, "x.y": [1, 2000.0]}
    for bad in ["novalue", "=3", "a..b=1", ".a=1"]:
        with pytest.raises(ConfigError, match="--set expects KEY=VALUE"):
            parse_set_items([bad])


def test_overrides_replace_mappings_and_never_touch_the_original():
    base = {"model": {"overrides": {"flow": {"v": 1.0}}, "input_mapping": "with_tau_m"}, "seed": 1}
    out = apply_overrides(base, {"model.overrides": {}, "seed": 3, "sim.duration_s": 0.5})
    assert out == {"model": {"overrides": {}, "input_mapping": "with_tau_m"}, "seed": 3, "sim": {"duration_s": 0.5}}
    assert base["model"]["overrides"] == {"flow": {"v": 1.0}}
    out = apply_overrides(base, {"model.overrides.flow.v": 2.0})
    assert out["model"]["overrides"] == {"flow": {"v": 2.0}}
    with pytest.raises(ConfigError, match=r"cannot set seed\.x: seed is 1, not a mapping"):
        apply_overrides(base, {"seed.x": 2})


def test_config_files_are_found_by_name_or_repository_path_from_any_directory(tmp_path, monkeypatch):
    from pathlib import Path

    from vesselbot_ros.config import load_yaml, resolve_config_path, shipped_config_dir

    monkeypatch.chdir(tmp_path)
    d = shipped_config_dir()
    assert resolve_config_path("sound_small_artery") == d / "sound_small_artery.yaml"
    assert resolve_config_path("sound_small_artery.yaml") == d / "sound_small_artery.yaml"
    assert resolve_config_path("config/campaigns/vf_error_seeds.yaml") == d / "campaigns" / "vf_error_seeds.yaml"
    assert load_yaml("paper_small_artery")["name"] == "paper_small_artery"
    mine = tmp_path / "sound_small_artery.yaml"  # a file of the user's wins over the shipped one
    mine.write_text("name: mine\n")
    assert resolve_config_path("sound_small_artery.yaml") == Path("sound_small_artery.yaml")
    with pytest.raises(ConfigError, match="'nowhere' does not exist; shipped: .*sound_small_artery"):
        load_yaml("nowhere")


def test_a_file_read_again_is_not_parsed_again_unless_it_changed_and_each_caller_gets_its_own_copy(tmp_path):
    from vesselbot_ros import config as cfg

    f = tmp_path / "c.yaml"
    f.write_text("a: {b: [1, 2]}\n")
    first = cfg.load_yaml(f)
    first["a"]["b"].append(3)  # a caller's change stays its own
    calls = []
    real = cfg.parse_yaml_text
    try:
        cfg.parse_yaml_text = lambda *a, **k: calls.append(1) or real(*a, **k)  # type: ignore[assignment]  # counts the parses
        assert cfg.load_yaml(f) == {"a": {"b": [1, 2]}} and calls == []
        f.write_text("a: {b: [1, 2, 4]}\n")  # the same size is no matter: the bytes are the key
        assert cfg.load_yaml(f) == {"a": {"b": [1, 2, 4]}} and calls == [1]
    finally:
        cfg.parse_yaml_text = real  # type: ignore[assignment]  # the real one back
