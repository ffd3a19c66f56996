"""OS errors of the commands that write (and print): one line naming the path and the reason."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest
from drive_logs import drag_45s_log

from pcvfe_drake import cli
from pcvfe_drake.cli import main
from pcvfe_drake.runs import output_paths
from pcvfe_drake.runs.drivelog import DriveLogWriter, write_drive_log

HAS_DEV_FULL = Path("/dev/full").exists()


def _error(capsys, argv) -> str:
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 2, captured
    assert "Traceback" not in captured.err
    return captured.err


def test_terrain_map_unknown_extension(tmp_path, capsys):
    out = tmp_path / "map.foo"
    err = _error(capsys, ["terrain-map", "--out", str(out)])
    assert str(out) in err and "'.foo'" in err and ".png" in err
    assert not out.exists()


def test_terrain_map_bad_places(tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    err = _error(capsys, ["terrain-map", "--out", str(a_file / "map.png")])
    assert f"{a_file} is a file" in err
    err = _error(capsys, ["terrain-map", "--out", str(tmp_path)])
    assert str(tmp_path) in err and "is a folder" in err


def test_unwritable_place_is_named(tmp_path, capsys, monkeypatch):
    # Tests run as root here, where chmod does not stop writes: the permission check is faked.
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    monkeypatch.setattr(
        output_paths.os, "access", lambda p, mode: Path(p) != locked and real_access(p, mode)
    )
    err = _error(capsys, ["terrain-map", "--out", str(locked / "sub" / "map.png")])
    assert f"no permission to write in {locked}" in err
    err = _error(capsys, ["diagnose", "whatever.csv", "--out", str(locked / "report")])
    assert f"no permission to write in {locked}" in err


@pytest.mark.skipif(not HAS_DEV_FULL, reason="needs /dev/full (Linux)")
def test_terrain_map_full_disk(tmp_path, capsys):
    full = tmp_path / "map.png"
    full.symlink_to("/dev/full")
    err = _error(capsys, ["terrain-map", "--out", str(full)])
    assert str(full) in err and "no space left" in err


class _FullStdout:
    """A stdout on a full disk."""

    def write(self, text):
        raise OSError(errno.ENOSPC, "No space left on device")

    def flush(self):
        pass

    def fileno(self):
        raise ValueError("no file descriptor")


def test_full_stdout_is_a_clean_error(tmp_path, capsys, monkeypatch):
    capsys.readouterr()
    monkeypatch.setattr("sys.stdout", _FullStdout())
    out = tmp_path / "map.png"
    code = main(["terrain-map", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert "<standard output>: no space left" in err
    assert out.stat().st_size > 1000  # the image written before the print is kept


@pytest.fixture(scope="module")
def small_log(tmp_path_factory, run_cache):
    df = drag_45s_log(run_cache)
    path = tmp_path_factory.mktemp("logs") / "drive.csv"
    write_drive_log(df, path)
    return path


def test_diagnose_out_is_checked_before_the_work(small_log, tmp_path, capsys, monkeypatch):
    a_file = tmp_path / "report.txt"
    a_file.write_text("keep me")

    def no_work(*args, **kwargs):
        raise AssertionError("the diagnosis ran although --out is unusable")

    monkeypatch.setattr("pcvfe_drake.workbench.report.diagnose", no_work)
    err = _error(capsys, ["diagnose", str(small_log), "--out", str(a_file)])
    assert str(a_file) in err and "is a file" in err
    assert a_file.read_text() == "keep me"
    err = _error(capsys, ["diagnose", str(small_log), "--out", str(a_file / "report")])
    assert f"{a_file} is a file" in err


def test_diagnose_full_disk_keeps_the_printed_report(small_log, tmp_path, capsys, monkeypatch):
    out = tmp_path / "report"

    def full_disk(report, wb, out_dir):
        raise OSError(errno.ENOSPC, "No space left on device", str(Path(out_dir) / "report.json"))

    monkeypatch.setattr("pcvfe_drake.workbench.report.write_report", full_disk)
    code = main(["diagnose", str(small_log), "--candidates", "drag", "--json", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 2
    report = json.loads(captured.out.strip().splitlines()[-1])  # the result is not lost
    assert report["ranked_effects"][0]["name"] == "drag"
    assert f"--out {out}" in captured.err and "no space left" in captured.err


def test_demo_and_export_clip_refuse_a_file_as_folder(tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for argv in (["demo", "--out", str(a_file)], ["export-clip", "--out", str(a_file)]):
        err = _error(capsys, argv)
        assert str(a_file) in err and "takes a folder" in err
    assert a_file.read_text() == "x"


@pytest.mark.skipif(not HAS_DEV_FULL, reason="needs /dev/full (Linux)")
def test_drive_log_writer_names_the_file_on_a_full_disk(tmp_path):
    path = tmp_path / "drive_log.csv"
    path.symlink_to("/dev/full")
    n = 5
    chunk = {c: np.zeros(n) for c in ("sx", "sy", "delta", "v", "psi", "psi_dot", "beta")}
    chunk.update(t=np.arange(n) * 0.1, steer_rate=np.zeros(n), accel=np.zeros(n))
    with DriveLogWriter(path) as writer:
        with pytest.raises(OSError) as info:
            writer.append(chunk)
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(path)


def test_describe_os_error():
    exc = PermissionError(errno.EACCES, "Permission denied", "/x/y")
    assert output_paths.describe_os_error(exc) == (
        "/x/y: permission denied; choose a folder you can write to"
    )
    assert output_paths.describe_os_error(FileNotFoundError("drive log x: no such file")) == (
        "drive log x: no such file"
    )


def test_ctrl_c_while_importing_is_one_line(capsys, monkeypatch):
    def interrupted(name):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.importlib, "import_module", interrupted)
    assert main(["fit", "x.csv"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "pcvfe: interrupted"
