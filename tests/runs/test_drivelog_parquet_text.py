"""A Parquet drive log whose text column holds bytes that are not UTF-8 (item 5 of issue 16)."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
from pcvfe_drake.runs.drivelog import DriveLogError, read_drive_log
from pcvfe_drake.vehicle.params import ford_escort

MARK = b"zqzq"  # replaced in the file's bytes by BAD (same length)
BAD = b"\xff\xfeqq"


def _bad_parquet(path, categorical: bool) -> None:
    """A valid log written without compression, then one label's bytes made invalid UTF-8."""
    params = ford_escort()
    t, S, U = s_curve_drive(params, [0.8], duration_s=4.0)
    df = drive_frame(t, S[0], U[0], terrain="sand", context=0, mu_true=0.8)
    terrain = ["sand"] * len(df)
    terrain[7] = MARK.decode()
    df["terrain"] = pd.Categorical(terrain) if categorical else terrain
    df.to_parquet(path, compression=None, index=False)
    raw = path.read_bytes()
    assert MARK in raw
    path.write_bytes(raw.replace(MARK, BAD))


def test_reader_names_the_column_and_row(tmp_path):
    path = tmp_path / "log.parquet"
    _bad_parquet(path, categorical=False)
    with pytest.raises(DriveLogError) as info:
        read_drive_log(path)
    assert "column 'terrain'" in str(info.value) and "UTF-8" in str(info.value)
    assert "row 7 " in str(info.value)
    lenient = read_drive_log(path, validate=False)
    assert str(lenient["terrain"].iloc[7]) == "\ufffd\ufffdqq"
    assert str(lenient["terrain"].iloc[0]) == "sand"


def test_dictionary_encoded_text_is_a_read_error(tmp_path):
    path = tmp_path / "log.parquet"
    _bad_parquet(path, categorical=True)  # pyarrow checks dictionary text while reading
    with pytest.raises(DriveLogError, match="cannot be read as parquet.*UTF8"):
        read_drive_log(path)


def test_fit_diagnose_and_lenient(tmp_path, capsys):
    path = tmp_path / "log.parquet"
    _bad_parquet(path, categorical=False)
    for argv in (["fit", str(path)], ["diagnose", str(path)]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "UTF-8" in err and "Traceback" not in err
    argv = ["fit", str(path), "--lenient", "--context-column", "terrain", "--json"]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert abs(report["contexts"]["sand"]["theta"]["mu"] - 0.8) < 0.01
