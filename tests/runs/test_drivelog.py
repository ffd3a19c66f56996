"""Tests of the drive-log format: round trips, validation findings, the incremental writer."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from pcvfe_drake.runs.drivelog import (
    REQUIRED_COLUMNS,
    DriveLogError,
    DriveLogWriter,
    read_drive_log,
    validate_drive_log,
    write_drive_log,
)
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import rk4_step


def simulated_log(n: int = 400, dt: float = 0.02) -> pd.DataFrame:
    """A physically consistent drive (ST model, steering wave) with the optional columns."""
    params = ford_escort()
    x = np.array([0.0, 0.0, 0.0, 8.0, 3.0, 0.0, 0.0])
    rows = []
    for k in range(n):
        t = k * dt
        u = np.array([0.15 * math.sin(0.8 * t), 0.3])
        rows.append([t, *x, *u])
        x = rk4_step(x, u, params, dt)
    df = pd.DataFrame(rows, columns=list(REQUIRED_COLUMNS))
    df["terrain"] = np.where(df["sx"] < 0, "sand", "brick")
    df["context"] = np.where(df["sx"] < 0, 1, -1)
    df["mu_true"] = np.where(df["sx"] < 0, 0.45, 0.8)
    df["image"] = [f"images/{k:05d}.png" for k in range(n)]
    df["lap"] = 1  # an extra column, kept
    return df


@pytest.fixture(scope="module")
def log() -> pd.DataFrame:
    return simulated_log()


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".csv.gz"])
def test_round_trip_keeps_values_and_extra_columns(tmp_path, log, suffix):
    path = write_drive_log(log, tmp_path / f"drive{suffix}")
    back = read_drive_log(path)
    assert list(back.columns) == list(log.columns)
    np.testing.assert_array_equal(
        back[list(REQUIRED_COLUMNS)].to_numpy(), log[list(REQUIRED_COLUMNS)]
    )
    assert back["context"].dtype == np.int64
    assert list(back["terrain"]) == list(log["terrain"])
    assert list(back["image"]) == list(log["image"])
    assert (back["lap"] == 1).all()


def test_valid_simulated_log_passes(log):
    assert validate_drive_log(log) is log


def test_every_problem_is_reported_at_once(log):
    bad = log.drop(columns=["beta"]).copy()
    bad.loc[5, "psi_dot"] = np.nan
    bad.loc[9, "sx"] = np.inf
    bad.loc[20, "t"] = bad.loc[19, "t"]  # repeated time stamp
    bad.loc[300:, "t"] += 4.0  # a gap before row 300
    bad["delta"] = np.degrees(bad["delta"]) * 30.0  # degrees, and large
    bad["v"] = bad["v"] * 3.6  # km/h
    with pytest.raises(DriveLogError) as info:
        validate_drive_log(bad, source="bad.csv")
    err = info.value
    text = str(err)
    assert "bad.csv" in text
    assert "missing column(s) ['beta']" in text
    assert "'psi_dot': NaN/missing at row 5" in text
    assert "'sx': infinite at row 9" in text
    assert "does not increase at row 20" in text
    assert "gaps" in text and "before row 300" in text
    assert "'delta'" in text and "degrees" in text
    assert "km/h" in text
    assert len(err.problems) == 7
    assert isinstance(err, ValueError)


def test_numeric_columns_are_checked_alike_whatever_their_dtype(log):
    # Columns of a numeric dtype skip the coercion text columns go through; both must report
    # the same problems (NaN, inf, ranges) in the same words.
    bad = log.copy()
    bad.loc[5, "psi_dot"] = np.nan
    bad.loc[9, "sx"] = -np.inf
    bad["delta"] = np.degrees(bad["delta"]) * 30.0
    bad["context"] = 0  # an int column
    as_text = bad.astype({c: object for c in ("psi_dot", "sx", "delta", "v", "context")})
    problems = []
    for table in (bad, as_text):
        with pytest.raises(DriveLogError) as info:
            validate_drive_log(table)
        problems.append(info.value.problems)
    assert problems[0] == problems[1] and len(problems[0]) == 3
    as_text.loc[7, "v"] = "fast"
    with pytest.raises(DriveLogError, match=r"'v': non-numeric values at row 7 \(e.g. 'fast'\)"):
        validate_drive_log(as_text)


def test_psi_in_degrees_is_detected_by_consistency(log):
    bad = log.copy()
    bad["psi"] = np.degrees(bad["psi"])  # no range limit on psi: found through psi_dot
    with pytest.raises(DriveLogError, match="psi in degrees"):
        validate_drive_log(bad)


def test_wrapped_heading_is_accepted(log):
    wrapped = log.copy()
    wrapped["psi"] = np.angle(np.exp(1j * wrapped["psi"]))  # crosses +-pi in this drive
    assert np.abs(np.diff(wrapped["psi"])).max() > 6.0
    validate_drive_log(wrapped)


def test_optional_column_checks(log):
    bad = log.copy()
    bad["context"] = bad["context"].astype(float)
    bad.loc[3, "context"] = 1.5
    bad.loc[4, "mu_true"] = -0.2
    bad["terrain"] = bad["terrain"].astype(object)
    bad.loc[6, "terrain"] = 7
    with pytest.raises(DriveLogError) as info:
        validate_drive_log(bad)
    text = str(info.value)
    assert "'context': not an integer >= -1 at row 3" in text
    assert "'mu_true': values outside" in text and "row 4" in text
    assert "'terrain': not text at row 6" in text


def test_max_gap_option(log):
    sparse = log.copy()
    sparse.loc[100:, "t"] += 0.5
    with pytest.raises(DriveLogError, match="gaps"):
        validate_drive_log(sparse)
    validate_drive_log(sparse, max_gap_s=math.inf)


def test_malformed_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_drive_log(tmp_path / "absent.csv")
    text_file = tmp_path / "notes.txt"
    text_file.write_text("hello")
    with pytest.raises(ValueError, match="unknown file type"):
        read_drive_log(text_file)
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"not parquet at all")
    with pytest.raises(DriveLogError, match="cannot be read as parquet"):
        read_drive_log(junk)
    strings = tmp_path / "strings.csv"
    strings.write_text(",".join(REQUIRED_COLUMNS) + "\n" + ",".join(["0"] * 9 + ["fast"]) + "\n")
    with pytest.raises(DriveLogError, match="'accel': non-numeric values at row 0"):
        read_drive_log(strings)


def test_writer_appends_and_survives_interruption(tmp_path, log):
    path = tmp_path / "live.csv"
    writer = DriveLogWriter(path)
    writer.append(log.iloc[:150])
    writer.append(log.iloc[150:300].to_dict("records"))
    # The run "dies" here without close(): everything appended is already on disk.
    partial = read_drive_log(path)
    assert len(partial) == 300
    np.testing.assert_array_equal(partial["v"].to_numpy(), log["v"].to_numpy()[:300])
    with pytest.raises(DriveLogError, match="not after"):
        writer.append(log.iloc[100:120])
    with pytest.raises(DriveLogError, match="differ"):
        writer.append(log.iloc[300:].drop(columns=["lap"]))
    bad = log.iloc[300:].copy()
    bad.loc[bad.index[2], "v"] = np.nan
    with pytest.raises(DriveLogError, match="NaN/missing at row 2"):
        writer.append(bad)
    writer.append(log.iloc[300:])
    writer.close()
    full = read_drive_log(path)
    assert len(full) == len(log)
    assert writer.rows_written == len(log)
    with pytest.raises(ValueError, match="closed"):
        writer.append(log.iloc[:1])
    with pytest.raises(ValueError, match="plain .csv"):
        DriveLogWriter(tmp_path / "live.parquet")


def test_unit_checks_can_be_turned_off_and_writer_accepts_a_spin(tmp_path, log):
    spin = log.copy()
    spin["psi_dot"] = spin["psi_dot"] * 40.0  # far beyond 6 rad/s, and inconsistent with psi
    with pytest.raises(DriveLogError, match="psi_dot"):
        validate_drive_log(spin)
    validate_drive_log(spin, check_units=False)
    with DriveLogWriter(tmp_path / "spin.csv") as writer:
        writer.append(spin)
    assert len(read_drive_log(tmp_path / "spin.csv", check_units=False)) == len(spin)
