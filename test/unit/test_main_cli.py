"""The ``vesselbot`` entry point: help of every command, closed pipes, OS errors as one line."""

from __future__ import annotations

import pytest

from vesselbot_ros.cli import COMMANDS, main

NESTED = {"bag": ("info", "repair"), "vessels": ("import",)}


def _help_argvs() -> list[list[str]]:
    out: list[list[str]] = [[], ["--help"], ["-h"]]
    for name in COMMANDS:
        out.append([name, "--help"])
        out.extend([name, sub, "--help"] for sub in NESTED.get(name, ()))
    return out


@pytest.mark.parametrize("argv", _help_argvs(), ids=lambda a: " ".join(a) or "(none)")
def test_help_of_every_command_prints_usage(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse exits 0 after --help
        code = exc.code
    out = capsys.readouterr().out
    assert code in (0, 2)
    assert out.startswith("usage: vesselbot")
    if argv and argv[0] in COMMANDS:
        assert f"vesselbot {argv[0]}" in out.splitlines()[0]
    else:
        for name in COMMANDS:
            assert name in out


def test_os_error_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    import vesselbot_ros.sim.simulate_cli as sim

    def full_disk(*a, **k):
        raise OSError(28, "No space left on device", str(tmp_path / "metrics.json"))

    monkeypatch.setattr(sim, "run_closed_loop", full_disk)
    cfg = tmp_path / "s.yaml"
    cfg.write_text("base: sound_small_artery\nname: s\nsim: {duration_s: 0.01}\nreference: {duration_s: 0.01}\n")
    assert main(["simulate", "--config", str(cfg), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0] and "metrics.json" in err[0]
