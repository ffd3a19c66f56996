"""`pcvfe replay` of damaged run folders: a named error before the replay starts (exit 2), or a
replay that stops early saying why on stderr (exit 1), never a normal summary."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from pcvfe_drake.cli import main


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A 2.5 s run of the default scenario (two saved frames: t = 0 and 2 s)."""
    out = tmp_path_factory.mktemp("replay") / "run"
    assert main(["simulate", "--duration", "2.5", "--no-meshcat", "--no-progress", "--out",
                 str(out)]) == 0  # fmt: skip
    return out


def _copy(run, tmp_path):
    folder = tmp_path / "damaged"
    shutil.copytree(run, folder)
    return folder


def _replay(folder, tmp_path, capsys) -> tuple[int, str, str]:
    code = main(["replay", str(folder), "--out", str(tmp_path / "replayed"), "--no-progress"])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _cut_last_row(path) -> None:
    """The log as a killed process may leave it: four rows, then half of a row's state."""
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:5], lines[5][:30]]) + "\n")


def _frames(folder):
    return sorted((folder / "frames").glob("*.png"))


DAMAGE = {
    "no drive log": (lambda f: (f / "drive_log.csv").unlink(), "has no drive_log.csv"),
    "no scenario.yaml": (lambda f: (f / "scenario.yaml").unlink(), "scenario.yaml"),
    "garbled scenario.yaml": (
        lambda f: (f / "scenario.yaml").write_text("rates: [: :\n"),
        "not valid YAML",
    ),
    "drive log cut mid-row": (lambda f: _cut_last_row(f / "drive_log.csv"), "drive_log.csv"),
    "garbled samples": (
        lambda f: (f / "fitter_samples.npz").write_bytes(b"not a zip"),
        "not a readable samples file",
    ),
    "samples of another shape": (
        lambda f: np.savez(
            f / "fitter_samples.npz",
            t_s=np.arange(3.0),
            state=np.zeros((3, 2)),
            actuation=np.zeros((3, 2)),
        ),  # fmt: skip
        "do not fit together",
    ),
    "a frame missing": (lambda f: _frames(f)[0].unlink(), "is missing"),
}


@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_a_damaged_run_folder_is_named_before_the_replay(run, tmp_path, capsys, case):
    damage, words = DAMAGE[case]
    folder = _copy(run, tmp_path)
    damage(folder)
    code, out, err = _replay(folder, tmp_path, capsys)
    assert code == 2, err
    assert words in err and "Traceback" not in err
    assert err.startswith("pcvfe replay: error: ")  # a drive log lists each problem below it


def test_an_unreadable_frame_stops_the_replay_with_the_reason_on_stderr(run, tmp_path, capsys):
    folder = _copy(run, tmp_path)
    _frames(folder)[-1].write_bytes(b"not a png")  # the frame at t = 2 s
    code, out, err = _replay(folder, tmp_path, capsys)
    assert code == 1
    assert "PARTIAL REPLAY: stopped at t = " in out
    assert "stopped early" in err and "cannot be read" in err and str(folder) in err


def test_samples_are_optional_a_replay_without_them_says_it_is_not_exact(run, tmp_path, capsys):
    folder = _copy(run, tmp_path)
    (folder / "fitter_samples.npz").unlink()
    code, out, err = _replay(folder, tmp_path, capsys)
    assert code == 0
    assert "not an exact rerun" in out and "held for 5 samples" in out
