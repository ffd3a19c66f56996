"""Messages that name the real problem: folders given for files, files for folders, user code."""

from __future__ import annotations

import pytest

from pcvfe_drake.cli import main


def _error(capsys, argv) -> str:
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 2, captured
    assert "Traceback" not in captured.err
    return captured.err


def test_features_on_a_folder(tmp_path, capsys):
    err = _error(capsys, ["features", str(tmp_path)])
    assert f"image {tmp_path} is a folder" in err and "does not exist" not in err


def test_clip_given_a_file(tmp_path, capsys):
    clip_json = tmp_path / "clip.json"
    clip_json.write_text("{}")
    image = tmp_path / "x.png"
    err = _error(capsys, ["features", "--clip", str(clip_json), str(image)])
    assert f"CLIP model folder {clip_json} is a file" in err and "does not exist" not in err
    assert f"use its folder {tmp_path}" in err


def test_fit_on_a_folder(tmp_path, capsys):
    # a run folder is read as pcvfe diagnose reads it: the drive log inside
    err = _error(capsys, ["fit", str(tmp_path)])
    assert f"run folder {tmp_path}: no drive log" in err and "no such file" not in err
    (tmp_path / "drive_log.csv").write_text("t\n")
    err = _error(capsys, ["fit", str(tmp_path)])
    assert f"drive log {tmp_path / 'drive_log.csv'}: " in err and "missing column" in err


def test_effects_file_sys_exit_is_reported(tmp_path, capsys):
    plugin = tmp_path / "quits.py"
    plugin.write_text("import sys\nsys.exit(3)\n")
    err = _error(capsys, ["diagnose", "whatever.csv", "--effects-file", str(plugin)])
    assert str(plugin) in err and "sys.exit(3)" in err


def test_effects_file_help_says_it_runs_code(capsys):
    with pytest.raises(SystemExit):
        main(["diagnose", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "RUNS with your permissions" in text
