"""``pcvfe fit`` says when a converged fit should not be trusted (docs/fitting.md, "Quality
warnings"): a parameter on a bound, a loss far above the noise, single samples that dominate,
columns unlike a measurement. The logs are read with --lenient, past the validation that would
refuse most of them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort


@pytest.fixture(scope="module")
def clean():
    params = ford_escort()
    t, S, U = s_curve_drive(params, [params.mu], duration_s=30.0, delta_amp_rad=0.15)
    return drive_frame(t, MeasurementNoise().apply(S[0], np.random.default_rng(0)), U[0])


def _fit(df, tmp_path, capsys, name="log.csv"):
    path = tmp_path / name
    df.to_csv(path, index=False)
    assert main(["fit", str(path), "--lenient", "--json"]) == 0
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])["contexts"]["all"]


def test_clean_log_has_no_warning(clean, tmp_path, capsys):
    entry = _fit(clean, tmp_path, capsys)
    q = entry["quality"]
    assert entry["warnings"] == [] and entry["converged"]
    assert q["at_bound"] == [] and q["influential_windows"] == []
    assert 1.0 < q["loss_noise_ratio"] < 3.0
    assert q["fit_percent"]["psi_dot"] > 90.0
    assert 6.0 < q["noise_loss"] < 8.0  # the noise of the log equals the residual scales


def test_flipped_steering_puts_mu_on_its_bound(clean, tmp_path, capsys):
    bad = clean.copy()
    bad["delta"] = -bad["delta"]
    entry = _fit(bad, tmp_path, capsys)
    assert entry["status"] == "converged"
    assert entry["quality"]["at_bound"] == ["mu"]
    assert entry["quality"]["loss_noise_ratio"] > 5.0
    text = " ".join(entry["warnings"])
    assert "sits on its lower bound" in text and "times what the measurement noise explains" in text


def test_one_impossible_sample_dominates(clean, tmp_path, capsys):
    bad = clean.copy()
    bad.loc[1234, "beta"] = 1.5
    entry = _fit(bad, tmp_path, capsys)
    windows = entry["quality"]["influential_windows"]
    assert windows and all(1220 <= w["start_row"] <= 1240 for w in windows)  # x0 smoothing: +-3
    assert any("single samples dominate" in w and "t = 12.3" in w for w in entry["warnings"])
    # ... and the table says it too.
    path = tmp_path / "log.csv"
    assert main(["fit", str(path), "--lenient"]) == 0
    assert "warning [all]: single samples dominate" in capsys.readouterr().out


def test_columns_unlike_a_measurement(clean, tmp_path, capsys):
    shuffled = clean.copy()
    shuffled["beta"] = np.random.default_rng(1).permutation(shuffled["beta"].to_numpy())
    entry = _fit(shuffled, tmp_path, capsys)
    assert [s.split()[0] for s in entry["quality"]["noisy_states"]] == ["beta"]
    zero = clean.copy()
    zero["beta"] = 0.0
    entry = _fit(zero, tmp_path, capsys)
    assert entry["quality"]["constant_states"] == ["beta"]
    assert any("beta constant in every window" in w for w in entry["warnings"])
