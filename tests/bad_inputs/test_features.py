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


def _png(width: int, height: int) -> bytes:
    import io

    import numpy as np
    from PIL import Image

    buffer = io.BytesIO()
    pixels = np.random.default_rng(0).integers(0, 255, (height, width, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(buffer, "PNG")
    return buffer.getvalue()


def test_an_image_claiming_too_many_pixels_is_named(tmp_path, capsys):
    import struct
    import zlib

    data = bytearray(_png(1, 1))
    data[16:24] = struct.pack(">II", 60000, 60000)  # the header's width and height
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(bytes(data))
    assert main(["features", str(bomb)]) == 2
    err = capsys.readouterr().err
    assert f"image {bomb} could not be decoded" in err and "Traceback" not in err


def test_a_too_small_image_is_named_with_its_file(tmp_path, capsys):
    good, tiny = tmp_path / "good.png", tmp_path / "tiny.png"
    good.write_bytes(_png(32, 32))
    tiny.write_bytes(_png(1, 1))
    assert main(["features", str(good), str(tiny)]) == 2
    err = capsys.readouterr().err
    assert f"image {tiny}: image is empty or too small (1x1 px" in err
