"""vesselbot_ros.atomic_io: an output is written whole or not at all, and output places are checked before the work."""

from __future__ import annotations

import collections
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from vesselbot_ros import atomic_io
from vesselbot_ros.atomic_io import OutputError, atomic_path, check_output_dir, check_output_file, write_text
from vesselbot_ros.errors import VesselbotError


def _on_a_full_disk(body: str) -> subprocess.CompletedProcess[str]:
    """Run ``body`` in a child whose files cannot grow (RLIMIT_FSIZE = 0: each write fails with EFBIG, root too)."""
    code = "import resource\nresource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))\n" + textwrap.dedent(body)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


def test_a_full_disk_leaves_the_old_file_intact_and_no_new_or_temporary_file(tmp_path: Path) -> None:
    old = tmp_path / "metrics.json"
    old.write_text('{"old": 1}\n')
    new = tmp_path / "plan.yaml"
    child = _on_a_full_disk(f"""
        from vesselbot_ros.atomic_io import OutputError, write_text
        for path in ({str(old)!r}, {str(new)!r}):
            try:
                write_text(path, "x" * 100_000)
            except OutputError as exc:
                print(exc)
    """)
    assert child.returncode == 0, child.stderr
    lines = child.stdout.splitlines()
    assert len(lines) == 2
    assert lines[0].startswith(f"cannot write {old} (File too large: the disk is full or a file size limit")
    assert lines[0].endswith("no partial file was left, an earlier metrics.json is unchanged")
    assert lines[1].startswith(f"cannot write {new} ")
    assert old.read_text() == '{"old": 1}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]  # no 0-byte plan.yaml, no temporary file


def test_an_error_while_drawing_leaves_the_old_file_and_no_temporary_file(tmp_path: Path) -> None:
    dest = tmp_path / "fig9a_trajectory.png"
    dest.write_bytes(b"old figure")
    with pytest.raises(ValueError, match="draw failed"), atomic_path(dest) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".png"  # matplotlib picks the format from the suffix
        tmp.write_bytes(b"half a figure")
        raise ValueError("draw failed")
    assert dest.read_bytes() == b"old figure"
    assert list(tmp_path.iterdir()) == [dest]


def test_a_new_file_replaces_the_old_whole_and_keeps_its_mode(tmp_path: Path) -> None:
    dest = tmp_path / "plan.yaml"
    dest.write_text("old")
    dest.chmod(0o640)
    assert write_text(dest, "new") == dest
    assert dest.read_text() == "new" and dest.stat().st_mode & 0o777 == 0o640
    fresh = write_text(tmp_path / "segments.csv", "a,b\n")
    umask = os.umask(0)
    os.umask(umask)
    assert fresh.stat().st_mode & 0o777 == 0o666 & ~umask  # as open() makes it, not mkstemp's 0600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.yaml", "segments.csv"]


def test_an_output_error_is_a_vesselbot_error_and_an_os_error() -> None:
    exc = atomic_io.write_error("out/metrics.json", OSError(28, "No space left on device"))
    assert isinstance(exc, VesselbotError) and isinstance(exc, OSError)
    assert exc.errno == 28 and exc.filename == "out/metrics.json"
    assert str(exc) == ("cannot write out/metrics.json (No space left on device: the disk is full or a file size "
                        "limit was reached); no partial file was left, an earlier metrics.json is unchanged")


def test_a_folder_on_a_full_disk_is_refused_and_left_as_it_was_found(tmp_path: Path) -> None:
    out = tmp_path / "new" / "out"
    child = _on_a_full_disk(f"""
        from vesselbot_ros.atomic_io import OutputError, check_output_dir
        try:
            check_output_dir({str(out)!r}, "--out")
        except OutputError as exc:
            print(exc)
    """)
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == (f"--out {out} is not writable (File too large: the disk is full or a file size "
                                    f"limit was reached); nothing was written")
    assert list(tmp_path.iterdir()) == []  # neither the folders it made nor its probe file


def test_too_little_free_space_names_the_folder_and_both_sizes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(atomic_io.shutil, "disk_usage", lambda p: usage(10**9, 10**9, 3 * 2**20))
    out = tmp_path / "new" / "report"
    with pytest.raises(OutputError, match=rf"^report folder {out}: the outputs need 8\.0 MiB free \(six figures\), "
                                          rf"only 3\.0 MiB is free on {tmp_path}; nothing was written$"):
        check_output_dir(out, "report folder", need_bytes=8 * 2**20, need_why="six figures")
    assert list(tmp_path.iterdir()) == []
    assert check_output_dir(out, "report folder", need_bytes=2 * 2**20) == out and out.is_dir()
    assert list(out.iterdir()) == []  # the probe is gone


def test_a_path_under_a_file_is_refused(tmp_path: Path) -> None:
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(OutputError, match=r"--out .*a_file/out: .*a_file is not a folder"):
        check_output_dir(tmp_path / "a_file" / "out", "--out")
    with pytest.raises(OutputError, match=r"--metrics-json .*a_file/m\.json: folder .*a_file does not exist"):
        check_output_file(tmp_path / "a_file" / "m.json", "--metrics-json")


def test_read_only_places_are_refused_before_any_work_as_root_too(tmp_path: Path) -> None:
    # a chmod 0o500 folder stops no one running as root (the tests do); sysfs refuses a new file, and a write to a
    # read-only attribute, whoever asks
    if not Path("/sys/kernel").is_dir():
        pytest.skip("no sysfs here")
    for path in (Path("/sys/vesselbot_metrics.json"), Path("/sys/kernel/uevent_seqnum")):
        if path.name == "uevent_seqnum" and not path.is_file():
            continue
        with pytest.raises(OutputError, match=rf"^--metrics-json {path} is not writable \(Permission denied\)"):
            check_output_file(path, "--metrics-json")
    assert not Path("/sys/vesselbot_metrics.json").exists()
    assert check_output_file(tmp_path / "m.json", "--metrics-json") == tmp_path / "m.json"
    assert list(tmp_path.iterdir()) == []  # checked, nothing written
