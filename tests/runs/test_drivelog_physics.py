"""Drive-log validation of samples no car can produce and of columns that contradict the
physics in sign or unit (docs/drive_log.md, "Physics checks")."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
from pcvfe_drake.runs.drivelog import DriveLogError, validate_drive_log
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort


@pytest.fixture(scope="module")
def clean():
    """30 s of S-curves at 8 m/s, 100 Hz, with the documented measurement noise."""
    params = ford_escort()
    t, S, U = s_curve_drive(params, [0.8], duration_s=30.0, delta_amp_rad=0.15)
    noisy = MeasurementNoise().apply(S[0], np.random.default_rng(0))
    return drive_frame(t, noisy, U[0])


def _problems(df) -> str:
    with pytest.raises(DriveLogError) as info:
        validate_drive_log(df, source="x.csv")
    return str(info.value)


def test_clean_noisy_log_passes(clean):
    assert validate_drive_log(clean) is clean


def test_single_impossible_side_slip(clean):
    bad = clean.copy()
    bad.loc[1234, "beta"] = 1.5  # passes the |beta| <= pi/2 range check
    text = _problems(bad)
    assert "column 'beta': physically impossible step at rows 1234, 1235" in text


def test_single_yaw_rate_and_steering_spikes(clean):
    bad = clean.copy()
    bad.loc[800, "psi_dot"] += 2.0
    bad.loc[1500, "delta"] -= 0.3
    text = _problems(bad)
    assert "column 'psi_dot': physically impossible step at rows 800, 801" in text
    assert "column 'delta': physically impossible step at rows 1500, 1501" in text


def test_sign_flipped_steering(clean):
    bad = clean.copy()
    bad["delta"] = -bad["delta"]
    bad["steer_rate"] = -bad["steer_rate"]
    text = _problems(bad)
    assert "turns against its steering" in text and "flip the sign" in text


def test_heading_bias(clean):
    bad = clean.copy()
    bad["psi"] += 0.3
    text = _problems(bad)
    assert "column 'psi': psi + beta differs from the direction of travel" in text
    assert "median -0.3" in text


def test_beta_sign_and_degrees(clean):
    params = ford_escort()
    # more slip than the clean fixture: a tighter S-curve on low friction
    t, S, U = s_curve_drive(params, [0.3], duration_s=30.0, delta_amp_rad=0.2)
    df = drive_frame(t, MeasurementNoise().apply(S[0], np.random.default_rng(1)), U[0])
    validate_drive_log(df)
    flipped = df.copy()
    flipped["beta"] = -flipped["beta"]
    assert "beta has the opposite sign" in _problems(flipped)
    # Gentle curves: |beta| in degrees stays under the pi/2 range check.
    t, S, U = s_curve_drive(params, [0.8], duration_s=30.0, delta_amp_rad=0.04)
    gentle = drive_frame(t, S[0], U[0])  # noise-free
    validate_drive_log(gentle)
    degrees = gentle.copy()
    degrees["beta"] = np.degrees(degrees["beta"])
    assert np.abs(degrees["beta"]).max() < np.pi / 2
    assert "beta in degrees?" in _problems(degrees)


def test_steer_rate_sign(clean):
    bad = clean.copy()
    bad["steer_rate"] = -bad["steer_rate"]
    assert "column 'steer_rate'" in _problems(bad)


def test_speed_and_yaw_rate_scale_errors(clean):
    fast = clean.copy()
    fast["v"] *= 1.15  # passed the old [0.5, 2] band; 10 % moved the fitted mu 1.05 -> 0.84
    assert "column 'v': v is 1.15 times the speed" in _problems(fast)
    half = clean.copy()
    half["psi_dot"] *= 0.5
    assert "column 'psi': psi changes 2.0" in _problems(half)
