"""`pcvfe fit` and `pcvfe diagnose`: the sizes the user controls are bounded before any work,
with the rows and memory the request implies (the answers themselves: tests of those commands)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.runs.resample import (
    MAX_RESAMPLE_HZ,
    MAX_RESAMPLED_ROWS,
    check_resampled_rows,
    resample_log,
)


@pytest.mark.parametrize("command", ["fit", "diagnose"])
@pytest.mark.parametrize("rate", ["1e6", "1001", "0", "-5", "nan", "inf"])
def test_a_resample_rate_beyond_the_bound_is_refused_before_the_log_is_read(
    tmp_path, capsys, command, rate
):
    missing = tmp_path / "never_read.csv"  # refused before the log is opened
    assert main([command, str(missing), "--resample", rate]) == 2
    err = capsys.readouterr().err
    assert "--resample" in err and "Traceback" not in err and "never_read" not in err
    if MAX_RESAMPLE_HZ < float(rate) < float("inf"):
        assert f"at most {MAX_RESAMPLE_HZ:g} Hz" in err and "GB" in err


def test_the_resampled_rows_are_bounded_with_an_estimate():
    assert check_resampled_rows(10.0, 100.0) == 1001
    with pytest.raises(ValueError, match=r"rows \(~.* GB for the fit\), more than"):
        check_resampled_rows(MAX_RESAMPLED_ROWS / 500.0 + 10.0, 1000.0, "long.csv")
    # A long log at an allowed rate is refused before the grid is allocated.
    t = np.array([0.0, 1500.0, 3000.0])
    log = pd.DataFrame({"t": t, "sx": t})
    with pytest.raises(ValueError, match="long.csv: 3000 s at --resample 1000 Hz"):
        resample_log(log, 1000.0, source="long.csv")


@pytest.mark.parametrize("speed", ["-1", "nan"])
def test_a_negative_speed_filter_is_refused(tmp_path, capsys, speed):
    assert main(["fit", str(tmp_path / "never_read.csv"), "--min-speed", speed]) == 2
    err = capsys.readouterr().err
    assert f"--min-speed must be >= 0 m/s, got {float(speed)}" in err and "Traceback" not in err
