"""`pcvfe features` on bad inputs: one line naming the image or the option, exit 2."""

from __future__ import annotations

import pytest

from pcvfe_drake.cli import main


@pytest.fixture
def not_an_image(tmp_path):
    path = tmp_path / "notes.png"
    path.write_text("not an image")
    return path


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["{missing}"], "does not exist"),
        (["{bad}"], "could not be decoded"),
        (["{folder}"], "is a folder, not an image file"),
        (["{bad}", "--top", "0"], "--top must be >= 1"),
        (["{bad}", "--clip", "{missing_dir}"], "CLIP model folder"),
        (["{bad}", "--lambda-c", "-1"], "lambda_c must be a finite number >= 0"),
        (["{bad}", "--lambda-c", "nan"], "lambda_c must be a finite number >= 0"),
    ],
)
def test_bad_feature_inputs_are_named(tmp_path, capsys, not_an_image, args, words):
    names = {
        "missing": tmp_path / "missing.png",
        "bad": not_an_image,
        "folder": tmp_path,
        "missing_dir": tmp_path / "no_model",
    }
    argv = ["features", *(a.format(**names) for a in args)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err
