"""The run folder (Drake-free): refusing an existing run, --overwrite, and OS errors that name
the path and the reason (``pcvfe simulate --out``)."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.runs.run_folder import RUN_DIRS, RUN_FILES, RunFolder, RunFolderError


def _old_run(root: Path) -> None:
    root.mkdir(parents=True)
    for name in RUN_FILES:
        (root / name).write_text("old")
    for name in RUN_DIRS:
        (root / name).mkdir()
        (root / name / "old.png").write_bytes(b"x")
    (root / "notes.txt").write_text("mine")


def test_a_folder_with_a_run_is_refused_unless_overwrite(tmp_path):
    root = tmp_path / "run"
    _old_run(root)
    with pytest.raises(RunFolderError, match=r"already holds a run \(drive_log.csv.*--overwrite"):
        RunFolder(root).prepare()
    assert (root / "summary.json").read_text() == "old"  # nothing touched
    removed = RunFolder(root).prepare(overwrite=True)
    assert sorted(removed) == sorted([*RUN_FILES, *RUN_DIRS])
    assert sorted(p.name for p in root.iterdir()) == ["notes.txt"]  # the user's file stays
    assert RunFolder(tmp_path / "new").prepare() == []
    assert RunFolder(root).prepare() == []  # an empty (or foreign-only) folder is fine


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: (p.write_text("x"), p)[1], "exists and is a file"),
        (lambda p: (p.write_text("x"), p / "sub" / "run")[1], "so no folder can be made under it"),
    ],
)
def test_out_that_is_or_lies_under_a_file_is_named(tmp_path, capsys, make, message):
    out = make(tmp_path / "taken")
    code = main(["simulate", "--duration", "1", "--no-meshcat", "--no-progress", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert str(out) in err and message in err


def test_an_unwritable_out_is_named_with_the_reason(tmp_path, capsys, monkeypatch):
    # Tests run as root here, so permissions cannot be taken away: the OS answer is simulated.
    def denied(self, *args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(self))

    monkeypatch.setattr(Path, "mkdir", denied)
    out = tmp_path / "locked" / "run"
    code = main(["simulate", "--duration", "1", "--no-meshcat", "--no-progress", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert f"cannot create the run folder {out}: permission denied" in err


def test_a_second_run_into_the_same_folder_is_refused_before_it_runs(tmp_path, capsys):
    out = tmp_path / "run"
    _old_run(out)
    code = main(["simulate", "--duration", "1", "--no-meshcat", "--no-progress", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "already holds a run" in err and "--overwrite" in err
    assert (out / "drive_log.csv").read_text() == "old"


def test_overwrite_replaces_the_old_run_and_says_so(tmp_path, capsys):
    out = tmp_path / "run"
    _old_run(out)
    args = ["simulate", "--duration", "0.5", "--no-meshcat", "--no-progress", "--out", str(out)]
    assert main([*args, "--overwrite"]) == 0
    printed = capsys.readouterr().out
    assert f"--overwrite: removed the previous run in {out}" in printed
    assert not (out / "playback.html").exists()  # the old page is gone, not left stale
    assert not (out / "frames" / "old.png").exists() and not (out / "figures" / "old.png").exists()
    assert (out / "summary.json").read_text() != "old" and (out / "notes.txt").exists()
