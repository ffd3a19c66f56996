"""The ``pcvfe demo`` command: runs the plant, prints the final state, writes a valid drive log."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.runs.drivelog import read_drive_log


def test_demo_writes_a_valid_log(tmp_path, capsys):
    assert main(["demo", "--duration", "1", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "final state after 1 s" in out and "terrain  sand" in out
    log = read_drive_log(tmp_path / "drive_log.csv")
    assert len(log) == 51  # 0.02 s logging over 1 s, both ends
    np.testing.assert_allclose(log["t"].iloc[-1], 1.0)
    assert (log["terrain"] == "sand").all() and (log["mu_true"] == 0.45).all()
    assert log["v"].iloc[-1] == pytest.approx(9.0, abs=1e-3)  # 8 m/s + 1 m/s^2 for 1 s


def test_demo_rejects_bad_duration(capsys):
    assert main(["demo", "--duration", "nan"]) == 2
    assert "--duration must be in" in capsys.readouterr().err
