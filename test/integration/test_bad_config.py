"""Bad configuration: `vesselbot run` exits 2 before any node starts, names key and value, leaves no bag."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

from vesselbot_ros import cli

REPO = Path(__file__).resolve().parents[2]
PAPER = REPO / "config" / "paper_small_artery.yaml"


def _config_with(tmp_path: Path, dotted: str, value: object) -> Path:
    """The paper config with one dotted key set (created if missing)."""
    doc = yaml.safe_load(PAPER.read_text())
    *parents, leaf = dotted.split(".")
    node = doc
    for p in parents:
        node = node.setdefault(p, {})
    node[leaf] = value
    out = tmp_path / "bad.yaml"
    out.write_text(yaml.safe_dump(doc))
    return out


# (dotted key, bad value, substrings the one-line error must contain)
CASES = [
    ("physics.vessel.unknown_key_m", 1.0, ["unknown_key_m"]),
    ("physics.robot.radius_m", "big", ["radius_m", "big"]),
    ("physics.robot.radius_m", -2.5e-4, ["radius_m", "-0.00025"]),
    ("physics.robot.radius_m", 1.5e-3, ["radius_m", "0.0015"]),  # lambda = 2 r / D = 1
    ("sim.control_rate_Hz", 0.0, ["control_rate_Hz", "0"]),
    ("imager.frame_rate_Hz", 0.0, ["frame_rate_Hz", "0"]),
    ("controller.gains.k1", -5.0, ["k1", "-5"]),
    ("observer.g2", 13.0, ["g2", "13"]),
    ("controller.stale_timeout_s", 0.0, ["stale_timeout_s", "0"]),
]


@pytest.mark.parametrize(("key", "value", "needles"), CASES, ids=[f"{c[0]}={c[1]}" for c in CASES])
def test_bad_config_exits_2_naming_key_and_value_without_bag(tmp_path, capsys, monkeypatch, key, value, needles):
    monkeypatch.chdir(tmp_path)
    bag = tmp_path / "bag"
    code = cli.main(["run", "--config", str(_config_with(tmp_path, key, value)), "--record-dir", str(bag),
                     "--duration", "0.01", "--quiet"])
    out, err = capsys.readouterr()
    assert code == 2, out + err
    line = err.strip().splitlines()[-1]
    assert line.startswith("vesselbot run: error:"), err
    for needle in needles:
        assert needle in line, (needle, line)
    assert not bag.exists()
    assert not (tmp_path / "runs").exists()  # no default run or log directory either
    assert "vesselbot run:" not in out  # the banner is printed only once the graph is about to start


def test_missing_config_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    missing = tmp_path / "nope.yaml"
    code = cli.main(["run", "--config", str(missing), "--record-dir", str(tmp_path / "bag"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert "nope.yaml" in err
    assert os.listdir(tmp_path) == []


def test_bad_command_line_value(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = cli.main(["run", "--config", str(PAPER), "--real-time-factor", "-1", "--record-dir", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert code == 2
    assert "--real-time-factor" in err and "-1" in err
    assert os.listdir(tmp_path) == []
