"""Friction fitting: window filtering, exact gradients, accuracy with a planted truth, honesty."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.fit_dataset import SKIP_REASONS, build_windows, windows_from_log
from pcvfe_drake.estimation.fit_loss import window_loss, window_loss_and_gradient
from pcvfe_drake.estimation.fit_options import (
    STATUS_DIVERGED,
    STATUS_TOO_LITTLE_DATA,
    FitOptions,
    FitResult,
    joint_options,
)
from pcvfe_drake.estimation.fitting import fit_adam, fit_contexts, fit_gauss_newton
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.handing.config import HandingConfig, Prior
from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import V

TERRAIN_MU = (0.3, 0.45, 0.6, 0.8)  # patchy grass, sand, concrete, brick


@pytest.fixture(scope="module")
def params():
    return ford_escort()


@pytest.fixture(scope="module")
def drives(params):
    """20 s S-curve drives at ~8 m/s on the four default terrains (ST truth, 100 Hz)."""
    return s_curve_drive(params, TERRAIN_MU, duration_s=20.0, phase_rad=[0.0, 1.0, 2.0, 3.0])


# ------------------------------------------------------------------ dataset filtering


def _oracle_counts(t, states, inputs, contexts, horizon, stride, v_min, dt):
    """Straightforward per-window loop: the reference for the vectorised filter."""
    counts = dict.fromkeys(SKIP_REASONS, 0)
    kept = []
    for s in range(0, len(t) - horizon, stride):
        w = range(s, s + horizon + 1)
        if not (
            all(np.isfinite(t[i]) and np.all(np.isfinite(states[i])) for i in w)
            and all(np.all(np.isfinite(inputs[i])) for i in w[:-1])
        ):
            counts["non_finite"] += 1
        elif any(abs(t[i + 1] - t[i] - dt) > 0.1 * dt for i in w[:-1]):
            counts["time_gap"] += 1
        elif len({contexts[i] for i in w}) > 1:
            counts["context_change"] += 1
        elif contexts[s] < 0:
            counts["no_context"] += 1
        elif any(states[i, V] < v_min for i in w):
            counts["low_speed"] += 1
        else:
            kept.append(s)
    return counts, kept


def test_window_filter_counts_each_reason_like_a_plain_loop():
    rng = np.random.default_rng(3)
    n, dt = 400, 0.01
    t = np.arange(n) * dt
    t[250:] += 0.05  # a time gap before sample 250
    states = rng.normal(size=(n, 7))
    states[:, V] = 5.0
    states[300:320, V] = 0.5  # slow segment
    inputs = rng.normal(size=(n, 2))
    states[60, 3] = np.nan
    inputs[120, 0] = np.inf
    contexts = np.zeros(n, dtype=int)
    contexts[150:200] = 1
    contexts[340:360] = -1  # noise
    split = build_windows(
        t, states, inputs, contexts, horizon=10, stride=3, v_min=1.0, x0_smoothing_s=0
    )
    expected, kept = _oracle_counts(t, states, inputs, contexts, 10, 3, 1.0, dt)
    assert split.skipped == expected
    assert all(expected[r] > 0 for r in SKIP_REASONS)
    assert split.n_candidates == len(range(0, n - 10, 3))
    assert split.n_windows == len(kept)
    starts = np.sort(np.concatenate([d.start for d in split.by_context.values()]))
    assert starts.tolist() == kept
    d0 = split.by_context[0]
    s = int(d0.start[4])
    np.testing.assert_array_equal(d0.x0[4], states[s])
    np.testing.assert_array_equal(d0.X[4], states[s + 1 : s + 11])
    np.testing.assert_array_equal(d0.U[4], inputs[s : s + 10])
    assert set(np.concatenate([d.start for d in split.by_context.values()])) & set(
        range(150 - 10, 200)
    ) == set(split.by_context[1].start.tolist())
    # Skips are attributed to the context of the window's first sample.
    per_context = sum(v for c in split.skipped_by_context.values() for v in c.values())
    assert per_context <= sum(expected.values())


def test_windows_from_log_uses_the_context_column_and_rejects_bad_input(drives):
    t, S, U = drives
    df = drive_frame(t[:300], S[0, :300], U[0, :300], terrain=["sand"] * 150 + ["brick"] * 150)
    split = windows_from_log(df, "terrain", stride=5)
    assert set(split.by_context) == {"sand", "brick"}
    assert split.skipped["context_change"] == 2  # windows starting at 140 and 145
    assert split.samples == {"sand": 150, "brick": 150}
    one = windows_from_log(df)
    assert set(one.by_context) == {"all"}
    with pytest.raises(ValueError, match="missing column"):
        windows_from_log(df.drop(columns=["beta"]))
    with pytest.raises(ValueError, match="context column 'context'"):
        windows_from_log(df, "context")
    bad_t = df.copy()
    bad_t.loc[10, "t"] = bad_t.loc[5, "t"]
    with pytest.raises(ValueError, match="strictly increasing"):
        windows_from_log(bad_t)


# ------------------------------------------------------------------ loss and gradient


def test_sensitivity_gradient_matches_finite_differences(params, drives):
    t, S, U = drives
    data = build_windows(t[:400], S[2, :400], U[2, :400], stride=20).by_context[0]
    theta = np.array([0.55, 18.0, 23.0])
    loss, grad = window_loss_and_gradient(theta, data, params)
    assert loss == pytest.approx(window_loss(theta, data, params), rel=1e-12)
    for i in range(3):
        h = 1e-6 * theta[i]
        plus, minus = theta.copy(), theta.copy()
        plus[i] += h
        minus[i] -= h
        fd = (window_loss(plus, data, params) - window_loss(minus, data, params)) / (2 * h)
        assert grad[i] == pytest.approx(fd, rel=1e-5), i


def test_heading_residual_is_wrapped(params, drives):
    t, S, U = drives
    data = build_windows(t[:200], S[1, :200], U[1, :200], stride=10).by_context[0]
    shifted = build_windows(t[:200], S[1, :200], U[1, :200], stride=10).by_context[0]
    shifted.X[..., 4] += 2 * np.pi  # the same headings, one turn apart
    theta = np.array([0.5, params.C_Sf, params.C_Sr])
    assert window_loss(theta, shifted, params) == pytest.approx(
        window_loss(theta, data, params), rel=1e-9
    )


# ------------------------------------------------------------------ accuracy


def test_mu_within_0p01_on_four_terrains_noise_free(params, drives):
    t, S, U = drives
    for i, mu in enumerate(TERRAIN_MU):
        data = build_windows(t, S[i], U[i], stride=10).by_context[0]
        result = fit_gauss_newton(data, params)
        assert result.converged, result.status
        assert abs(result.mu - mu) < 0.01, (mu, result.mu)
        assert result.loss < 1e-2 * result.loss_initial
        assert result.std[0] < 0.01 and np.isnan(result.std[1])
        assert not result.warnings


def test_mu_within_0p03_on_four_terrains_with_measurement_noise(params, drives):
    t, S, U = drives
    rng = np.random.default_rng(7)
    noise = MeasurementNoise()
    errors = []
    for i, mu in enumerate(TERRAIN_MU):
        measured = noise.apply(S[i], rng)
        result = fit_gauss_newton(build_windows(t, measured, U[i]).by_context[0], params)
        assert result.converged
        errors.append(result.mu - mu)
        # The residual variance matches the noise model (loss ~ sum of unit variances).
        assert 5.0 < result.loss < 20.0
    assert np.max(np.abs(errors)) < 0.03, errors


def test_raw_initial_state_is_biased_by_noise_and_smoothing_fixes_it(params, drives):
    """The documented errors-in-variables bias of eq. 5b (x0 = noisy measurement)."""
    t, S, U = drives
    rng = np.random.default_rng(11)
    measured = MeasurementNoise().apply(S[3], rng)
    raw_data = build_windows(t, measured, U[3], stride=10, x0_smoothing_s=0).by_context[0]
    raw = fit_gauss_newton(raw_data, params)
    smooth = fit_gauss_newton(build_windows(t, measured, U[3], stride=10).by_context[0], params)
    assert raw.mu - 0.8 > 0.005
    assert abs(smooth.mu - 0.8) < abs(raw.mu - 0.8)


def test_adam_reaches_the_gauss_newton_loss_more_slowly(params, drives):
    t, S, U = drives
    data = build_windows(t[:600], S[2, :600], U[2, :600], stride=20).by_context[0]
    start = np.array([0.75, params.C_Sf, params.C_Sr])
    gn = fit_gauss_newton(data, params, start)
    adam = fit_adam(data, params, start, max_steps=400, target_loss=gn.loss * 1.001 + 1e-9)
    assert adam.status == "target_reached"
    assert adam.iterations > 5 * gn.iterations
    assert abs(adam.mu - gn.mu) < 0.01


# ------------------------------------------------------------------ identifiability and honesty


def test_joint_fit_without_priors_is_flagged_ill_conditioned(params, drives):
    t, S, U = drives
    rng = np.random.default_rng(5)
    data = build_windows(t, MeasurementNoise().apply(S[1], rng), U[1]).by_context[0]
    free = fit_gauss_newton(data, params, options=joint_options(params, rel_sigma=None))
    assert free.ill_conditioned
    assert any("mu*C_Sf" in w for w in free.warnings)
    with_priors = fit_gauss_newton(data, params, options=joint_options(params))
    assert not with_priors.ill_conditioned
    assert any("priors determine" in w for w in with_priors.warnings)
    # The identifiable products are recovered either way.
    for r in (free, with_priors):
        assert r.theta[0] * r.theta[1] == pytest.approx(0.45 * params.C_Sf, rel=0.05)
    assert np.all(np.isfinite(with_priors.std))


def test_straight_driving_carries_no_information_on_mu(params):
    n = 300
    t = np.arange(n) * 0.01
    states = np.zeros((n, 7))
    states[:, 0] = 8.0 * t
    states[:, V] = 8.0
    data = build_windows(t, states, np.zeros((n, 2))).by_context[0]
    result = fit_gauss_newton(data, params, np.array([0.5, params.C_Sf, params.C_Sr]))
    assert result.mu == pytest.approx(0.5)
    assert np.isinf(result.std[0])
    assert any("no information" in w for w in result.warnings)


def test_too_little_data_keeps_the_start_and_says_so(params, drives):
    t, S, U = drives
    data = build_windows(t[:60], S[0, :60], U[0, :60]).by_context[0]
    start = np.array([0.7, params.C_Sf, params.C_Sr])
    result = fit_gauss_newton(data, params, start)
    assert result.status == STATUS_TOO_LITTLE_DATA and not result.converged
    np.testing.assert_array_equal(result.theta, start)
    assert "too little data" in result.warnings[0]
    results = fit_contexts(build_windows(t[:60], S[0, :60], U[0, :60]), params)
    assert results[0].status == STATUS_TOO_LITTLE_DATA


def test_non_finite_rollouts_are_reported_as_diverged(params, drives):
    t, S, U = drives
    data = build_windows(t[:400], S[0, :400], U[0, :400]).by_context[0]
    data.x0[:, V] = 1e300  # the rollout overflows at every theta
    result = fit_gauss_newton(data, params)
    assert result.status == STATUS_DIVERGED and not result.converged
    assert np.all(np.isfinite(result.theta))


def test_bounds_hold(params, drives):
    t, S, U = drives
    data = build_windows(t[:500], S[0, :500], U[0, :500]).by_context[0]
    options = FitOptions(mu_bounds=(0.4, 1.5))
    result = fit_gauss_newton(data, params, options=options)
    assert result.mu == pytest.approx(0.4)  # truth 0.3 lies below the bound
    assert result.converged


def test_estimator_keeps_prior_then_fits_then_survives_divergence(params, drives):
    t, S, U = drives
    est = ContextEstimator(params, LiveFitConfig())
    for k in range(100):  # 1 s: fewer than 20 windows of stride 5
        est.add_sample(t[k], S[2, k], U[2, k], 4.0)
    est.add_sample(t[100], np.full(7, np.nan), U[2, 100], 4.0)
    est.add_sample(t[101], S[2, 101], U[2, 101], -1.0)
    assert est.refit(1.0) == [4]
    entry = est.table(1.0).get(4)
    assert entry.status == "too_little_data" and "using the prior" in entry.message
    np.testing.assert_array_equal(est.theta_for(4), params.theta)
    assert est.rejected_samples == 1 and est.noise_samples == 1
    for k in range(102, 600):
        est.add_sample(t[k], S[2, k], U[2, k], 4.0)
    est.refit(6.0)
    good = est.table(6.0).get(4)
    assert good.fits == 1 and abs(good.mu - 0.6) < 0.01
    est.add_sample(t[600], S[2, 600], U[2, 600], 4.0)

    def diverging(data, params_, theta0, options):
        return FitResult(
            theta=np.array([np.nan, 1.0, 1.0]),
            std=np.full(3, np.nan),
            loss=np.nan,
            loss_initial=np.nan,
            n_windows=data.n_windows,
            windows_skipped={},
            converged=False,
            status=STATUS_DIVERGED,
            iterations=1,
        )

    est.refit(7.0, fit=diverging)
    after = est.table(7.0).get(4)
    assert after.diverged == 1 and after.status == "diverged"
    assert after.theta == good.theta
    assert np.all(np.isfinite(est.theta_for(4)))
    # Unknown contexts get the prior.
    np.testing.assert_array_equal(est.theta_for(-1), params.theta)
    np.testing.assert_array_equal(est.theta_for(99), params.theta)


def test_a_10_hz_log_is_fitted_with_rk4_substeps(params):
    """Logs slower than 100 Hz: rollouts take 10 ms RK4 substeps with the logged input held."""
    t, S, U = s_curve_drive(params, [0.45], duration_s=10.0, hold_steps=10)
    t10, S10, U10 = t[::10], S[0, ::10], U[0, ::10]
    data = build_windows(t10, S10, U10, horizon=5, stride=1).by_context[0]
    assert data.dt == pytest.approx(0.1)
    result = fit_gauss_newton(data, params)
    assert result.converged and abs(result.mu - 0.45) < 0.01, result.mu
    # One 0.1 s RK4 step per sample instead: unstable/inaccurate, far off.
    coarse = fit_gauss_newton(data, params, options=FitOptions(max_step_s=0.1))
    assert coarse.loss > 100 * result.loss


def test_short_noise_keeps_the_last_context_estimate_then_falls_back_to_the_prior():
    params = ford_escort()
    handing = HandingConfig(noise_hold_s=0.5, unknown=Prior(), confirm_rise_s=0.0)
    est = ContextEstimator(params, LiveFitConfig(handing=handing))
    state = np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    est.add_sample(0.0, state, [0.0, 0.0], [3])
    slot = est._slots[3]
    slot.estimate = replace(slot.estimate, theta=(0.45, params.C_Sf, params.C_Sr), fits=1)
    np.testing.assert_allclose(est.theta_for(), [0.45, params.C_Sf, params.C_Sr])
    est.add_sample(0.3, state, [0.0, 0.0], [-1])  # 0.3 s of noise: the lower, the context's
    assert est.theta_for()[0] == 0.45
    est.add_sample(0.6, state, [0.0, 0.0], [-1])  # 0.6 s: the prior
    np.testing.assert_allclose(est.theta_for(), est.prior_theta)
    assert est.theta_for(-1)[0] == params.mu  # an explicit noise id is always the prior


def test_a_refit_runs_with_one_blas_thread(params, drives):
    from threadpoolctl import threadpool_info, threadpool_limits

    t, S, U = drives
    est = ContextEstimator(params, LiveFitConfig())
    for k in range(300):
        est.add_sample(t[k], S[2, k], U[2, k], 4.0)
    seen = []

    def recording(data, params_, theta0, options):
        seen.append([p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"])
        return fit_gauss_newton(data, params_, theta0, options)

    with threadpool_limits(limits=2, user_api="blas"):
        assert est.refit(3.0, fit=recording) == [4]
        outside = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    assert seen and all(n == 1 for n in seen[0])
    assert outside and all(n == 2 for n in outside)  # restored after the refit
