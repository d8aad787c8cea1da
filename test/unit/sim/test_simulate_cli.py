"""``vesselbot simulate`` on a full disk: each output whole or not at all, one line naming the path, exit 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from vesselbot_ros.testing import cli_on_a_full_disk

ROOT = Path(__file__).resolve().parents[3]
SOUND = ROOT / "config" / "sound_small_artery.yaml"
OLD = {"metrics.json": '{"old": 1}\n', "timeseries.npz": "old series", "scenario.yaml": "name: old\n"}


@pytest.mark.parametrize("fill_after", ["", "vesselbot_ros.sim.simulate_cli:run_closed_loop"],
                         ids=["full-before-the-run", "full-after-the-run"])
def test_a_full_disk_leaves_the_earlier_outputs_and_no_empty_or_probe_file(tmp_path: Path, fill_after: str) -> None:
    out = tmp_path / "o"
    out.mkdir()
    for name, text in OLD.items():
        (out / name).write_text(text)
    child = cli_on_a_full_disk(["simulate", "--config", str(SOUND), "--out", str(out), "--duration", "0.05",
                                "--set", "reference.duration_s=0.05"], fill_after=fill_after)
    err = child.stderr.strip().splitlines()
    assert child.returncode == 2, child.stderr
    assert len(err) == 1 and err[0].startswith("vesselbot simulate: error: ")
    assert "File too large: the disk is full or a file size limit was reached" in err[0]
    # the message names the path: the folder refused before the run, or the file that could not be written after it
    assert (f"--out {out} is not writable" in err[0] if not fill_after
            else f"cannot write {out / 'metrics.json'} " in err[0] and "metrics.json is unchanged" in err[0])
    assert {p.name: p.read_text() for p in out.iterdir()} == OLD  # no 0-byte file, no temporary or probe file
