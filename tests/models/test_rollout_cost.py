"""The rollout's shortcuts give the numbers of the direct computations: values an effect shares
within one evaluation of the right-hand side (``StepContext.cache``), the noise scales of all
columns at once, the starts' costs from one batched rollout and trials evaluated with their
Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.models.chassis_effects import wheel_slip_offsets
from pcvfe_drake.models.data import (
    CORRELATED_NOISE_RATIO,
    combine_stride_estimates,
    robust_noise_sigmas,
    sigma_from_fourth_difference_mad,
    window_starts,
)
from pcvfe_drake.models.estimate import fit, training_cost, training_costs
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import StepContext, get_effect, prepare, synth

VP = ford_escort()
SHIPPED = ["peak_tyre", "axle_stiffness", "roll_camber", "track_slip", "wheel_force_steer"]


def _states(n: int = 6, seed: int = 0):
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 7))
    x[:, 2] = rng.normal(0.0, 0.05, n)
    x[:, 3] = rng.uniform(3.0, 12.0, n)
    x[:, 5] = rng.normal(0.0, 0.5, n)
    x[:, 6] = rng.normal(0.0, 0.03, n)
    return x


def _ctx(x, mu):
    n = x.shape[0]
    return StepContext(x, np.zeros((n, 0)), np.zeros(n), np.zeros(n), VP, mu=mu)


def _params(name, n, **values):
    effect = get_effect(name)
    p = {q.name: np.full(n, values.get(q.name, q.initial)) for q in effect.params}
    return effect, p


def test_shared_values_are_reused_only_within_one_evaluation_and_for_the_same_inputs():
    x = _states()
    n = x.shape[0]
    mu = np.full(n, 0.7)
    rng = np.random.default_rng(1)
    alphas = rng.normal(0.0, 0.08, (2, n))
    loads = (np.full(n, 5200.0), np.full(n, 4800.0))
    c_alpha = 0.7 * 20.0 * loads[0]

    tyre, p = _params("peak_tyre", n, k_s=0.3)
    shared = _ctx(x, mu)
    shared.axle = "front"
    for alpha in alphas:  # two wheels of one axle: the same load and stiffness objects
        direct = _ctx(x, mu)
        direct.axle = "front"
        assert np.array_equal(
            tyre.tire(alpha, loads[0], c_alpha, p, shared),
            tyre.tire(alpha, loads[0], c_alpha, p, direct),
        )
    other = tyre.tire(alphas[0], loads[1], c_alpha, p, shared)  # a new load: formed afresh
    fresh = _ctx(x, mu)
    fresh.axle = "front"
    assert np.array_equal(other, tyre.tire(alphas[0], loads[1], c_alpha, p, fresh))
    _, q = _params("peak_tyre", n, k_s=1.0)  # other parameters: formed afresh too
    fresh = _ctx(x, mu)
    fresh.axle = "front"
    assert np.array_equal(
        tyre.tire(alphas[0], loads[1], c_alpha, q, shared),
        tyre.tire(alphas[0], loads[1], c_alpha, q, fresh),
    )

    track, p = _params("track_slip", n, t=1.39, k_lt=-0.85)
    shared = _ctx(x, mu)
    for axle, lever in (("front", VP.lf), ("rear", -VP.lr)):
        shared.axle = axle
        left, right, share = track.wheel_slips(shared, p)
        expected = wheel_slip_offsets(x, lever, p["t"])
        assert np.array_equal(left, expected[0]) and np.array_equal(right, expected[1])
        shift = np.clip(p["k_lt"] * x[:, 3] * x[:, 5] / VP.g, -0.9, 0.9)
        assert np.array_equal(share, 0.5 * (1.0 - shift))

    camber, p = _params("roll_camber", n, f0=-0.037, f1=0.05, s0=0.0027)
    shared = _ctx(x, mu)
    a = x[:, 3] * x[:, 5]
    s = np.tanh(a / 0.5)
    for fz in loads:
        shift, side = camber.tire_offsets(fz, shared, p)
        assert np.array_equal(shift, p["s0"] * s)
        assert np.array_equal(side, fz * (p["f0"] * s + p["f1"] * a / VP.g))


def test_rollout_of_the_shipped_effects_matches_hooks_evaluated_one_call_at_a_time():
    """The model's right-hand side with the hooks' per-evaluation values equals the same
    right-hand side where every hook call sees a fresh context (nothing shared)."""
    model = WorkbenchModel(VP, SHIPPED)
    x = _states(8, seed=3)
    n = x.shape[0]
    theta = np.tile(model.initial_theta(), (n, 1))
    theta[:, 0] = np.linspace(0.5, 1.0, n)
    base, eff = model._unpack(theta, np.zeros(n, dtype=int))
    u = np.column_stack([np.full(n, 0.1), np.linspace(-3.0, 3.0, n)])
    shared = model.rhs(x, u, base, eff)

    original = StepContext.__init__

    class Forgetful(dict):
        def __setitem__(self, key, value):  # nothing is kept: every call forms its values
            pass

    def init(self, *args, **kwargs):
        original(self, *args, **kwargs)
        self.cache = Forgetful()

    try:
        StepContext.__init__ = init
        direct = model.rhs(x, u, base, eff)
    finally:
        StepContext.__init__ = original
    assert np.array_equal(shared, direct)


def _noise_sigma_1d(y, max_stride):
    """The definition (``robust_noise_sigma``'s docstring), one signal at a time."""
    estimates = []
    for stride in range(1, max_stride + 1):
        d4 = y[4 * stride :] - 4 * y[3 * stride : -stride] + 6 * y[2 * stride : -2 * stride]
        d4 = d4 - 4 * y[stride : -3 * stride] + y[: -4 * stride]
        if d4.size < 5:
            break
        estimates.append(1.4826 * np.median(np.abs(d4 - np.median(d4))) / np.sqrt(70.0))
    if not estimates:
        return float(np.std(y)) or 1.0
    top = max(estimates)
    return top if top > CORRELATED_NOISE_RATIO * estimates[0] else estimates[0]


@pytest.mark.parametrize("n", [8, 40, 3000])
def test_noise_scales_of_all_columns_at_once_equal_one_signal_at_a_time(n):
    rng = np.random.default_rng(n)
    t = np.linspace(0.0, 30.0, n)
    y = np.column_stack([np.sin(t), np.cos(0.3 * t), np.full(n, 2.0), t])
    y[:, 0] += 0.01 * rng.standard_normal(n)
    y[:, 1] += np.repeat(0.02 * rng.standard_normal(n // 4 + 1), 4)[:n]  # correlated noise
    y[:, 3] += 0.001 * rng.standard_normal(n)
    got = robust_noise_sigmas(y, 10)
    expected = [_noise_sigma_1d(y[:, i], 10) for i in range(y.shape[1])]
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=0.0)


@pytest.fixture(scope="module")
def drive():
    df = synth.simulate_truths(
        [synth.Truth(mu=0.8, mu_peak=0.7)], VP, duration_s=12.0, rate_hz=50.0, seed=4
    )[0]
    return prepare(df, "synthetic", min_duration_s=5.0)


def test_the_starts_costs_from_one_batched_rollout_equal_one_rollout_each(drive):
    model = WorkbenchModel(VP, ["peak_tyre"])
    starts = window_starts(drive, 25, 25, "all", 1)
    thetas = [model.initial_theta() * f for f in (1.0, 0.8, 0.6)]
    batched = training_costs(model, thetas, drive, starts, 25, burn_in=5)
    single = [training_cost(model, th, drive, starts, 25, burn_in=5) for th in thetas]
    assert batched == pytest.approx(single, rel=1e-12)


def test_trials_with_their_jacobian_reach_the_same_fit(drive):
    model = WorkbenchModel(VP, ["peak_tyre"])
    fixed = np.array([p.effect is not None for p in model.params])
    starts = window_starts(drive, 25, 12, "all", 1)
    kwargs = dict(theta0=model.initial_theta(), fixed=fixed, burn_in=5, max_iter=15)
    apart = fit(model, drive, starts, 25, **kwargs)
    together = fit(model, drive, starts, 25, jacobian_at_trials=True, **kwargs)
    assert together.theta == pytest.approx(apart.theta, abs=1e-9)
    assert together.std == pytest.approx(apart.std, rel=1e-6, nan_ok=True)  # k_s held: NaN


def _noise_sigmas_along_columns(y, max_stride):
    """The noise scales computed along ``y``'s (strided) columns, the form the contiguous
    rows of :func:`robust_noise_sigmas` replace."""
    estimates = []
    for s in range(1, max_stride + 1):
        d4 = y[s * 4 :] - 4 * y[s * 3 : -s] + 6 * y[s * 2 : -2 * s]
        d4 = d4 - 4 * y[s : -3 * s] + y[: -4 * s]
        if d4.shape[0] < 5:
            break
        mad = np.median(np.abs(d4 - np.median(d4, axis=0)), axis=0)
        estimates.append(sigma_from_fourth_difference_mad(mad))
    return combine_stride_estimates(estimates, y)


@pytest.mark.parametrize("n", [6, 25, 2000, 2001])
def test_noise_scales_along_contiguous_rows_are_bit_identical_to_along_columns(n):
    rng = np.random.default_rng(n)
    y = np.cumsum(rng.standard_normal((n, 7)), axis=0) * 0.01
    y[:, 2] = np.repeat(y[::3, 2], 3)[:n]  # runs of equal values: ties in the medians
    for arr in (y, np.asfortranarray(y), y[:, :1]):
        np.testing.assert_array_equal(
            robust_noise_sigmas(arr, 10), _noise_sigmas_along_columns(arr, 10)
        )
    y[n // 2, 4] = np.nan
    np.testing.assert_array_equal(robust_noise_sigmas(y, 10), _noise_sigmas_along_columns(y, 10))
