"""Long logs: the fit uses at most ``max_windows`` windows per context, evenly spaced (bounded
memory), and says so."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.estimation.fit_dataset import build_windows
from pcvfe_drake.estimation.fitting import fit_gauss_newton
from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort


@pytest.fixture(scope="module")
def noisy_drive():
    params = ford_escort()
    t, S, U = s_curve_drive(params, [0.6], duration_s=40.0)
    noisy = MeasurementNoise().apply(S[0], np.random.default_rng(1))
    return params, t, noisy, U[0]


def test_cap_keeps_evenly_spaced_windows(noisy_drive):
    params, t, S, U = noisy_drive
    full = build_windows(t, S, U, max_windows=None)
    n = full.by_context[0].n_windows
    capped = build_windows(t, S, U, max_windows=200)
    data = capped.by_context[0]
    assert data.n_windows == 200 and capped.available == {0: n} and full.available == {0: n}
    gaps = np.diff(data.start)
    assert data.start[0] == full.by_context[0].start[0]
    assert data.start[-1] == full.by_context[0].start[-1]
    assert gaps.max() - gaps.min() <= full.by_context[0].start[1] - full.by_context[0].start[0]
    # The estimate from the subset agrees with the full fit within its own uncertainty.
    a = fit_gauss_newton(full.by_context[0], params)
    b = fit_gauss_newton(data, params)
    assert abs(a.mu - b.mu) < 3.0 * b.std[0] and b.std[0] > a.std[0]
    with pytest.raises(ValueError, match="max_windows"):
        build_windows(t, S, U, max_windows=1)


def test_fit_command_reports_the_cap(noisy_drive, tmp_path, capsys):
    _, t, S, U = noisy_drive
    path = tmp_path / "drive.csv"
    drive_frame(t, S, U).to_csv(path, index=False)
    assert main(["fit", str(path), "--max-windows", "100", "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    entry = report["contexts"]["all"]
    assert report["max_windows"] == 100 and entry["n_windows"] == 100
    assert entry["windows_available"] == 799
    assert main(["fit", str(path), "--max-windows", "100"]) == 0
    assert "100 of 799 windows fitted" in capsys.readouterr().out
    assert main(["fit", str(path), "--max-windows", "0", "--json"]) == 0
    entry = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["contexts"]["all"]
    assert entry["n_windows"] == entry["windows_available"] == 799


def test_workbench_analyses_evenly_spaced_excerpts_of_a_long_log(run_cache):
    from drive_logs import seed3_logs

    from pcvfe_drake.models.data import excerpt_rows, prepare, window_starts

    rows = excerpt_rows(1000, max_samples=120, excerpts=6)
    assert rows.size == 120 and rows[0] == 0 and rows[-1] == 999
    starts = rows[::20]
    assert np.array_equal(starts, np.linspace(0, 980, 6).round())
    assert np.array_equal(excerpt_rows(100, max_samples=120), np.arange(100))

    df = seed3_logs(run_cache)["drag"]  # planted drag, 90 s at 20 Hz
    full = prepare(df, "log", max_samples=None)
    data = prepare(df, "log", max_samples=1200)
    assert full.n == full.rows_in_log == len(df)
    assert data.n == 1200 and data.rows_in_log == len(df)
    kept = excerpt_rows(len(df), 1200)
    assert np.array_equal(data.t, full.t[kept]) and np.array_equal(data.x0, full.x0[kept])
    assert np.array_equal(data.sigma, full.sigma)  # noise scales from the whole log
    # No window spans the time gap between two excerpts, whatever the number of blocks.
    for n_blocks in (6, 4):
        s = window_starts(data, 30, 1, "all", n_blocks)
        assert s.size > 0
        span = data.t[s + 30] - data.t[s]
        assert np.allclose(span, 30 * data.dt)
