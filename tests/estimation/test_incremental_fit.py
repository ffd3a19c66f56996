"""Incremental refits of the effect model (``estimation/incremental_fit.py``): the stored windows'
quadratic models, the forgetting rule, relinearisation, equality with the batch fit within its
standard deviation, and the estimator's refit scheduling (relabel resets, declared latency)."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator, window_members
from pcvfe_drake.estimation.effect_fit import EffectFitter
from pcvfe_drake.estimation.incremental_fit import (
    MAX_REJECTIONS,
    RELINEARISE_SCALE,
    Problem,
    WindowInformation,
    minimise_quadratic,
    quadratic,
    window_sums,
)
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.models import least_squares as lsq
from pcvfe_drake.models.effect_model import EffectModel
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth

STATES = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]
SHIPPED = [  # the effect model paper_eval held before the calibrated car models: mu alone is fitted
    "peak_tyre:k_s=0.0",
    "axle_stiffness:k_f=1.01,k_r=1.24",
    "roll_camber:f0=-0.037,f1=0,s0=0.0027",
    "track_slip:t=1.39,k_lt=-0.85",
]


@pytest.fixture(scope="module")
def drive():
    """24 s at 50 Hz of a brush-tyre truth (stiffness mu 0.8, peak 0.7)."""
    df = synth.simulate_truths(
        [synth.Truth(mu=0.8, mu_peak=0.7)], duration_s=24.0, rate_hz=50.0, seed=2, substeps=2
    )[0]
    return df["t"].to_numpy(), df[STATES].to_numpy(), df[["steer_rate", "accel"]].to_numpy()


def test_window_sums_rebuild_the_batch_normal_equations():
    rng = np.random.default_rng(0)
    n_windows, steps, sigma = 6, 4, np.array([0.5, 2.0, 1.0])
    J = rng.normal(size=(n_windows * steps * 3, 2))
    r = rng.normal(size=n_windows * steps * 3)
    ee, ej, jj = window_sums(r, J, n_windows, sigma, np.array([0, 1]))
    info = WindowInformation(
        np.arange(n_windows), np.zeros((n_windows, 2)), ee, ej, jj, np.zeros(2)
    )
    ssr, gram, scores = quadratic(info, np.zeros(2), sigma)
    assert ssr == pytest.approx(float(r @ r))
    np.testing.assert_allclose(gram, J.T @ J)
    np.testing.assert_allclose(scores, lsq.window_scores(J, r, n_windows))
    # away from the linearisation point: the linear model r + J d, exactly
    d = np.array([0.3, -0.2])
    ssr_d, _, scores_d = quadratic(info, d, sigma)
    r_d = r + J @ d
    assert ssr_d == pytest.approx(float(r_d @ r_d))
    np.testing.assert_allclose(scores_d, lsq.window_scores(J, r_d, n_windows))
    # the covariances from the sums equal those from the Jacobian
    np.testing.assert_allclose(
        lsq.hac_covariance_from_scores(gram, scores, 2), lsq.hac_covariance(J, r, n_windows, 2)
    )
    np.testing.assert_allclose(
        lsq.covariance_from_gram(gram, float(r @ r), r.size), lsq.covariance(J, float(r @ r))
    )
    # the minimiser of the quadratic is the linear least-squares solution (inside the bounds)
    problem = Problem(
        np.array([True, True]),
        sigma,
        np.full(2, -10.0),
        np.full(2, 10.0),
        np.ones(2),
        np.zeros(2),
        np.zeros(2),
    )
    step = minimise_quadratic(info, np.zeros(2), problem)
    np.testing.assert_allclose(step, -np.linalg.lstsq(J, r, rcond=None)[0], atol=1e-8)


def test_incremental_refits_equal_the_batch_fit_within_its_std(drive):
    t, S, U = drive
    fitter = EffectFitter(ford_escort(), SHIPPED, model_error_rel=0.11)
    n0 = np.searchsorted(t, 14.0)
    first, info = fitter.refit(t[:n0], S[:n0], U[:n0], None, 1.0489)
    assert not first.incremental and info.keys.size == first.n_windows
    for end_s in (16.0, 19.0, 24.0):
        n = np.searchsorted(t, end_s)
        result, info = fitter.refit(t[:n], S[:n], U[:n], info, 1.0489)
        batch = fitter(t[:n], S[:n], U[:n], previous=first.model_theta, mu_start=1.0489)
        assert result.incremental and result.n_windows == batch.n_windows
        assert info.keys.size == batch.n_windows
        # one batched rollout per iteration (the new windows, then the relinearised ones)
        assert 1 <= result.rollouts <= fitter.max_iterations
        std = batch.model_std[0]
        assert abs(result.model_theta[0] - batch.model_theta[0]) <= std
        assert result.model_std[0] == pytest.approx(std, rel=0.5)
        assert result.data_end_s == pytest.approx(batch.data_end_s)


def test_forgetting_keeps_the_batch_window_set(drive):
    t, S, U = drive
    fitter = EffectFitter(ford_escort(), SHIPPED, max_windows=12)
    n0 = np.searchsorted(t, 12.0)
    _, info = fitter.refit(t[:n0], S[:n0], U[:n0], None, 1.0489)
    n = np.searchsorted(t, 20.0)
    _, info = fitter.refit(t[:n], S[:n], U[:n], info, 1.0489)
    from pcvfe_drake.estimation.effect_fit import drive_data_from_arrays

    data = drive_data_from_arrays(t[:n], S[:n], U[:n], "test")
    starts, _, _ = fitter.windows(data)
    np.testing.assert_array_equal(info.keys, np.round(data.t[starts] / data.dt).astype(int))
    assert info.keys.size == 12


def test_a_far_estimate_is_relinearised(drive):
    t, S, U = drive
    fitter = EffectFitter(ford_escort(), SHIPPED)
    n = np.searchsorted(t, 18.0)
    batch, info = fitter.refit(t[:n], S[:n], U[:n], None, 1.0489)
    far = info.estimate.copy()
    far[0] += 10 * RELINEARISE_SCALE * fitter.model.scales()[0]
    moved = WindowInformation(info.keys, info.theta, info.ee, info.ej, info.jj, far)
    result, again = fitter.refit(t[:n], S[:n], U[:n], moved, 1.0489)
    assert result.rollouts >= 1  # every window re-evaluated away from its point
    assert abs(result.model_theta[0] - batch.model_theta[0]) <= 0.5 * batch.model_std[0]
    np.testing.assert_array_equal(again.keys, info.keys)


def test_a_refit_started_on_the_flat_side_of_the_peak_comes_down(drive):
    """From a stale estimate far above the friction the data used, the models linearised there
    send mu to its lower bound, where the cost is far higher: the refit retries shorter steps
    (as the batch fit's Levenberg-Marquardt damps a rejected step) instead of staying put."""
    t, S, U = drive
    fitter = EffectFitter(ford_escort(), SHIPPED)
    n = np.searchsorted(t, 18.0)
    batch, info = fitter.refit(t[:n], S[:n], U[:n], None, 1.0489)
    stale = info.estimate.copy()
    stale[0] = 1.2
    moved = WindowInformation(info.keys, info.theta, info.ee, info.ej, info.jj, stale)
    result, _ = fitter.refit(t[:n], S[:n], U[:n], moved, 1.0489)
    warm = fitter(t[:n], S[:n], U[:n], previous=stale, mu_start=1.0489)
    assert abs(warm.model_theta[0] - batch.model_theta[0]) <= batch.model_std[0]
    assert abs(result.model_theta[0] - batch.model_theta[0]) <= batch.model_std[0]
    assert result.rollouts <= fitter.max_iterations * (1 + MAX_REJECTIONS)


def test_estimator_resets_on_relabel_and_publishes_after_the_declared_latency(drive):
    t, S, U = drive
    est = ContextEstimator(
        ford_escort(),
        LiveFitConfig(
            model=EffectModel(effects=SHIPPED), sample_period_s=0.02, effect_min_windows=5
        ),
    )
    n = np.searchsorted(t, 10.0)
    for k in range(n):
        est.add_sample(t[k], S[k], U[k], 0)
    assert est.start_refit(float(t[n - 1]))
    assert not est.start_refit(float(t[n - 1]))  # one in flight
    for k in range(n, n + 10):  # 0.2 s more data, not used by the refit started before it
        est.add_sample(t[k], S[k], U[k], 0)
    assert est.finish_refit(float(t[n + 9]), latency_s=0.3) is None  # not yet due
    assert est.finish_refit(float(t[n + 9]) + 0.1, latency_s=0.3) == [0]
    entry = est.table().get(0)
    assert entry.fitted and entry.data_end_s <= t[n - 1]
    p50, p99, count = entry.sample_to_estimate_s
    assert count > 0 and 0.3 <= p50 <= p99 <= t[n - 1] + 0.4
    assert entry.sample_to_refit_s[2] == 0  # the first fit's samples waited for its data
    # a refit 0.5 s later publishes the 0.2 s received after the first fit's start and more:
    # those waits are counted over every sample and over the refits' alone
    for k in range(n + 10, n + 25):
        est.add_sample(t[k], S[k], U[k], 0)
    assert est.start_refit(float(t[n + 24]))
    assert est.finish_refit(float(t[n + 24]) + 0.3, latency_s=0.3) == [0]
    later = est.table().get(0)
    r50, r99, r_count = later.sample_to_refit_s
    assert r_count == later.sample_to_estimate_s[2] - count == 25
    published_s = float(t[n + 24]) + 0.3
    # the newest waited the latency, the oldest since just after the first fit's data
    assert 0.3 <= r50 <= r99 <= published_s - entry.data_end_s + 0.01 + 1e-9
    assert r99 < p99
    assert later.sample_to_estimate_s[1] >= r99  # over all samples: the first fit's wait too
    assert est._slots[0].fit_info is not None
    est.relabel(t[:n], np.full(n, -1), 0.02, version=1)  # the samples leave the context
    assert est._slots[0].fit_info.keys.size == 0  # every window re-evaluated next time


def test_window_members_mark_the_samples_a_window_holds():
    windows = (None, np.array([0, 5, 20]), 4, 1)
    expected = np.zeros(30, dtype=bool)
    expected[0:10] = True  # windows 0..4 and 5..9
    expected[20:25] = True
    np.testing.assert_array_equal(window_members(30, windows), expected)
    np.testing.assert_array_equal(window_members(22, windows), expected[:22])  # cut at the end


def _two_visits(est, t, S, U) -> None:
    """Feed ``est`` a first visit of context 0 to 6.3 s, 2.7 s of noise and a second visit
    from 9 s, refitting at the first visit's end and at 2 Hz in the second."""
    end1, start2 = int(np.searchsorted(t, 6.3)), int(np.searchsorted(t, 9.0))
    for k in range(t.size):
        est.add_sample(t[k], S[k], U[k], 0 if k < end1 or k >= start2 else -1)
        if k == end1 - 1 or (k >= start2 and (k - start2) % 25 == 24):
            est.refit(float(t[k]))


def test_samples_no_window_holds_are_not_counted_as_waiting(drive):
    """A visit's end shorter than a window's stride reaches no estimate: its samples have no
    wait (counted at the next visit's fit they would read the time between the visits)."""
    t, S, U = drive
    config = LiveFitConfig(
        model=EffectModel(effects=SHIPPED), sample_period_s=0.02, effect_min_windows=5
    )
    est = ContextEstimator(ford_escort(), config)
    _two_visits(est, t, S, U)
    entry = est.table().get(0)
    first_end = 6.0  # the first visit's last window (1 s horizon, 0.5 s stride) ends there
    trailing = int(np.sum((t > first_end + 1e-9) & (t < 6.3)))
    assert trailing > 5 and entry.fits > 20
    mine = (t < 6.3) | (t >= 9.0 - 1e-9)
    up_to_end = int(np.sum(mine & (t <= entry.data_end_s + 1e-9)))
    assert entry.sample_to_estimate_s[2] <= up_to_end - trailing
    assert entry.sample_to_refit_s[1] < 2.0  # none waited the 2.7 s between the visits


def test_the_single_track_fit_counts_only_the_samples_its_windows_hold(drive):
    """The paper's single-track fitter (no effect model) publishes the end of its newest window
    as the data it used, and a sample no window holds (the end of a visit) has no wait."""
    t, S, U = drive
    est = ContextEstimator(
        ford_escort(), LiveFitConfig(model=EffectModel(effects=[]), sample_period_s=0.02)
    )
    assert est._effect_fitter is None
    _two_visits(est, t, S, U)
    entry = est.table().get(0)
    assert entry.fitted and entry.fits > 20
    assert entry.data_end_s < t[-1]  # the newest window ends before the newest sample
    held = est._slots[0]
    mine = (t < 6.3) | (t >= 9.0 - 1e-9)
    assert entry.sample_to_estimate_s[2] < int(np.sum(mine & (t <= held.estimate_data_end_s)))
    assert entry.sample_to_refit_s[1] < 2.0  # none waited the 2.7 s between the visits
