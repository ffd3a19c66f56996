"""Is a friction peak shown by the data? (``fit_quality.peak_evidence``): a drive near its peak
shows it, one far below it does not, not even where a fit settles just above the friction
the drive used (the low fit a model error in one bend produces)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcvfe_drake.estimation.effect_fit import (
    EffectFitter,
    drive_data_from_arrays,
    friction_used,
    small_slip_stiffness,
)
from pcvfe_drake.estimation.fit_quality import (
    PEAK_SHOWN_CHI2,
    kept_peak_evidence,
    no_peak_theta,
    peak_check,
    peak_evidence,
    peak_not_shown,
)
from pcvfe_drake.estimation.incremental_fit import RELINEARISE_SCALE
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth

VP = ford_escort()
STATES = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]
PEAK_TYRE = [{"name": "peak_tyre", "fixed": {"k_s": 0.0}}]


@pytest.fixture(scope="module")
def drives():
    """The same programme on a tyre whose peak it nears (0.45) and one far above it (3.0);
    the stiffness does not follow the peak (``lateral_peak``)."""
    truths = [
        synth.Truth(mf_peak=peak, mf_stiffness_exponent=0.0, mf_shape=1.35) for peak in (0.45, 3.0)
    ]
    logs = synth.simulate_truths(truths, VP, duration_s=30.0, seed=2)
    return [
        (d["t"].to_numpy(), d[STATES].to_numpy(), d[["steer_rate", "accel"]].to_numpy())
        for d in logs
    ]


def evidence(fitter, t, x, u, theta):
    data = drive_data_from_arrays(t, x, u, "test")
    starts, horizon, burn_in = fitter.windows(data)
    overlap = fitter.horizon_s / fitter.stride_s
    return peak_evidence(fitter.model, theta, data, starts, horizon, burn_in, overlap)


def test_a_drive_near_its_peak_shows_it_one_far_below_does_not(drives):
    fitter = EffectFitter(VP, PEAK_TYRE)
    (t, x, u), (t2, x2, u2) = drives
    near = fitter(t, x, u, None, VP.mu)
    assert abs(near.theta[0] - 0.45) < 0.05
    assert friction_used(t, x, lateral_only=True) > 0.6 * 0.45  # the drive came near it
    assert evidence(fitter, t, x, u, near.model_theta) > PEAK_SHOWN_CHI2
    assert peak_not_shown(fitter, near) == ""

    used = friction_used(t2, x2, lateral_only=True)
    assert used < 0.25 * 3.0  # far below the peak
    far = fitter(t2, x2, u2, None, VP.mu)
    assert evidence(fitter, t2, x2, u2, far.model_theta) < PEAK_SHOWN_CHI2
    # a fit put just above the friction the drive used, as a model error in its most
    # cornering window puts it: "near the limit" by construction, and not shown
    knee = far.model_theta.copy()
    knee[0] = used / 0.6
    assert evidence(fitter, t2, x2, u2, knee) < PEAK_SHOWN_CHI2
    far.model_theta[:] = knee
    assert "the data do not show the peak" in peak_not_shown(fitter, far)


@pytest.mark.parametrize("k_s", [0.0, 1.0, 0.5])
def test_the_tyre_without_a_peak_keeps_the_fitted_small_slip_stiffness(k_s):
    fitter = EffectFitter(VP, [{"name": "peak_tyre", "fixed": {"k_s": k_s}}])
    theta = fitter.theta_init.copy()
    theta[0] = 0.4
    flat = no_peak_theta(fitter.model, theta)
    assert flat[0] == pytest.approx(400.0)
    # (the fitted tyre bends slightly even at the stiffness probe's 1e-4 rad)
    np.testing.assert_allclose(
        small_slip_stiffness(fitter.model, flat),
        small_slip_stiffness(fitter.model, theta),
        rtol=1e-4,
    )


def test_too_few_windows_or_a_bad_fit_is_no_evidence(drives):
    fitter = EffectFitter(VP, PEAK_TYRE)
    t, x, u = drives[0]
    theta = fitter.theta_init.copy()
    theta[0] = math.nan
    assert math.isnan(evidence(fitter, t, x, u, theta))
    data = drive_data_from_arrays(t, x, u, "test")
    _, horizon, burn_in = fitter.windows(data)
    empty = np.zeros(0, dtype=int)
    assert math.isnan(peak_evidence(fitter.model, theta, data, empty, horizon, burn_in, 2.0))


@pytest.mark.parametrize("which", [0, 1])
def test_an_incremental_refit_rolls_out_only_the_new_windows_of_the_tyre_without_a_peak(
    drives, which
):
    """The live estimator's peak evidence does what the incremental refit does: after a batch
    fit both tyres on every window; then the tyre without a peak only on the new windows (the
    others kept, at the point they were rolled out at), the fitted tyre's cost the refit's own,
    and the same verdict as the full evidence (near: shown, far: not)."""
    import pcvfe_drake.models.estimate as estimate

    fitter = EffectFitter(VP, PEAK_TYRE, max_windows=40)
    t, x, u = drives[which]
    n0 = np.searchsorted(t, 20.0)
    first, info = fitter.refit(t[:n0], x[:n0], u[:n0], None, VP.mu)
    ratio, sums = kept_peak_evidence(fitter, first, None)
    data, starts, horizon, burn_in = first.windows
    overlap = fitter.horizon_s / fitter.stride_s
    assert ratio == peak_evidence(
        fitter.model, first.model_theta, data, starts, horizon, burn_in, overlap
    )
    assert sums.keys.size == first.n_windows
    rows_rolled = []
    original = estimate.whitened_errors

    def counting(model, theta_rows, *args, **kwargs):
        rows_rolled.append(len(theta_rows))
        return original(model, theta_rows, *args, **kwargs)

    n = np.searchsorted(t, 23.0)
    result, info = fitter.refit(t[:n], x[:n], u[:n], info, VP.mu)
    assert result.incremental
    estimate.whitened_errors = counting
    try:
        again, new_sums = kept_peak_evidence(fitter, result, sums)
    finally:
        estimate.whitened_errors = original
    old = np.isin(new_sums.keys, sums.keys)
    kept_rows = np.searchsorted(sums.keys, new_sums.keys[old])
    point = result.model_theta[~fitter.fixed]
    near = np.all(
        np.abs(sums.points[kept_rows] - point)
        <= RELINEARISE_SCALE * fitter.model.scales()[~fitter.fixed],
        axis=1,
    )
    assert rows_rolled == [int((~old).sum() + (~near).sum())] and (~old).sum() >= 1
    if which == 0:  # near its peak the estimate stays put: only the new windows
        assert near.all()
    np.testing.assert_array_equal(new_sums.ee[old][near], sums.ee[kept_rows][near])
    data, starts, horizon, burn_in = result.windows
    exact = peak_evidence(fitter.model, result.model_theta, data, starts, horizon, burn_in, overlap)
    assert again == pytest.approx(exact, rel=0.05, abs=0.5)
    reason, _ = peak_check(fitter, result, sums)
    assert reason == peak_not_shown(fitter, result)
    assert (reason == "") == (which == 0)
    # a window far from the estimate is rolled out again
    moved = type(sums)(sums.keys, sums.points + 1.0, sums.ee)
    _, redone = kept_peak_evidence(fitter, result, moved)
    np.testing.assert_allclose(
        redone.points, np.tile(result.model_theta[~fitter.fixed], (redone.keys.size, 1))
    )
