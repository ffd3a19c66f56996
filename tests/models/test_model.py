"""The workbench model, effects, estimator and metrics on known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pcvfe_drake.models.data import robust_noise_sigma, window_starts
from pcvfe_drake.models.effects import unregister_effect
from pcvfe_drake.models.estimate import _residuals_and_jacobian, fit
from pcvfe_drake.models.model import applied_inputs
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import rollout
from pcvfe_drake.workbench import (
    Effect,
    EffectParam,
    WorkbenchModel,
    get_effect,
    known_effects,
    prepare,
    register_effect,
    synth,
)
from pcvfe_drake.workbench.compare import fit_percent


@pytest.fixture(scope="module")
def clean_df():
    return synth.simulate_truths(
        [synth.Truth()], duration_s=30.0, rate_hz=20.0, noise=None, substeps=2
    )[0]


@pytest.fixture(scope="module")
def clean(clean_df):
    return prepare(clean_df, "clean", min_duration_s=10.0)


def test_baseline_equals_the_vehicle_rollout(clean):
    model = WorkbenchModel()
    starts = np.array([50, 200, 400])
    Z = model.simulate(model.initial_theta(), clean, starts, 20)
    U = clean.u[starts[:, None] + np.arange(20)]
    X = rollout(clean.x0[starts], U, ford_escort(), clean.dt)
    assert np.max(np.abs(Z - X)) < 1e-10


def test_applied_inputs_equal_vehicle_constraints():
    from pcvfe_drake.vehicle.single_track import constrain_inputs

    vp = ford_escort()
    rng = np.random.default_rng(1)
    x = rng.normal(size=(5000, 7))
    x[:, 2] *= 0.8
    x[:, 3] = rng.uniform(-15.0, 50.0, 5000)
    u = rng.normal(size=(5000, 2)) * [0.5, 12.0]
    expected = constrain_inputs(x, u, vp)[0]
    assert np.array_equal(np.stack(applied_inputs(x, u, vp), axis=1), expected)


@pytest.mark.parametrize(
    "name, null",
    [
        ("drag", {"CdA": 0.0}),
        ("rolling_resistance", {"c_rr": 0.0}),
        ("steering_lag", {"tau": 0.0}),
        ("input_delay", {"T": 0.0}),
        ("grade", {"gx": 0.0, "gy": 0.0}),
        ("steering_offset", {"d0": 0.0}),
    ],
)
def test_effects_at_their_null_value_are_the_baseline(clean, name, null):
    base = WorkbenchModel()
    model = base.with_effects(name)
    theta = model.initial_theta()
    for key, value in null.items():
        theta[model.param_names.index(f"{name}.{key}")] = value
    starts = np.array([30, 300])
    Z0 = base.simulate(base.initial_theta(), clean, starts, 30)
    Z1 = model.simulate(theta, clean, starts, 30)
    assert np.max(np.abs(Z1[:, :, :7] - Z0)) < 1e-12


def test_steering_lag_state_follows_the_exact_lag(clean):
    tau = 0.15
    lag = get_effect("steering_lag")
    init = lag.initial_states(clean, np.arange(clean.n), {"tau": np.full(clean.n, tau)})[:, 0]
    t, delta = clean.t, clean.x0[:, 2]
    sol = solve_ivp(
        lambda tt, y: [(np.interp(tt, t, delta) - y[0]) / tau],
        (0.0, t[-1]),
        [delta[0]],
        t_eval=t,
        max_step=0.005,
        rtol=1e-10,
        atol=1e-12,
    )
    late = t > 1.0  # after the start transient (the filter starts in steady ramp)
    assert np.max(np.abs(init[late] - sol.y[0][late])) < 1e-4


def test_input_delay_of_whole_steps_shifts_the_command(clean):
    model = WorkbenchModel().with_effects("input_delay")
    base = WorkbenchModel()
    starts = np.array([100, 250])
    Z1 = model.simulate(np.array([1.0489, 3 * clean.dt]), clean, starts, 20)
    shifted = prepare_shifted(clean, 3)
    Z0 = base.simulate(base.initial_theta(), shifted, starts, 20)
    assert np.max(np.abs(Z1 - Z0)) < 1e-12


def prepare_shifted(data, k):
    import copy

    d = copy.copy(data)
    u = data.u.copy()
    u[k:, 1] = data.u[:-k, 1]
    u[:k, 1] = data.u[0, 1]
    d.u = u
    return d


def test_finite_difference_sensitivity_matches_exact_rollout_sensitivity(clean):
    model = WorkbenchModel()
    starts = np.array([60, 260])
    theta = model.initial_theta()
    r, jac = _residuals_and_jacobian(model, theta, clean, starts, 20, True)
    U = clean.u[starts[:, None] + np.arange(20)]
    _, S = rollout(clean.x0[starts], U, ford_escort(), clean.dt, sensitivities=True)
    idx = [2, 3, 4, 5, 6]
    exact = (S[:, 1:, idx, 0] / clean.sigma[idx]).reshape(-1)
    assert np.allclose(jac[:, 0], exact, rtol=1e-5, atol=1e-6 * np.abs(exact).max())


def test_fit_recovers_mu_on_noise_free_data(clean):
    model = WorkbenchModel()
    starts = window_starts(clean, 20, 20, "train")
    res = fit(model, clean, starts, 20, theta0=np.array([0.6]))
    assert abs(res.theta[0] - 1.0489) < 1e-3
    assert res.converged


def test_user_defined_effect_in_a_few_lines(clean):
    @register_effect
    class AccelGain(Effect):
        """The drivetrain delivers a fraction k of the commanded acceleration."""

        name = "accel_gain_test"
        params = (EffectParam("k", "-", 0.5, 1.5, 1.0, 0.1, 1.0, "acceleration gain"),)

        def accel(self, accel, ctx, p):
            return p["k"] * accel

    try:
        assert "accel_gain_test" in known_effects()
        model = WorkbenchModel().with_effects("accel_gain_test")
        starts = window_starts(clean, 20, 20, "train")
        # measurements produced by the composed model itself with k = 0.8
        fake = prepare_from_model(clean, model, np.array([1.0489, 0.8]))
        res = fit(model, fake, starts, 20)
        assert abs(res.theta[1] - 0.8) < 1e-3
    finally:
        unregister_effect("accel_gain_test")
    assert "accel_gain_test" not in known_effects()


def prepare_from_model(data, model, theta):
    import copy

    d = copy.copy(data)
    Z = model.simulate(theta, data, np.array([0]), data.n - 1)[0]
    d.x = Z[:, :7].copy()
    d.x0 = d.x.copy()
    return d


def test_unknown_and_duplicate_effects_are_clear_errors():
    with pytest.raises(ValueError, match="known effects: drag, rolling_resistance"):
        get_effect("warp_drive")
    with pytest.raises(ValueError, match="more than once"):
        WorkbenchModel().with_effects("drag", "drag")
    with pytest.raises(ValueError, match="base parameter"):
        WorkbenchModel(base_params=("nope",))


def test_library_has_the_named_effects_with_bounds_and_units():
    names = known_effects()
    for name in ("drag", "rolling_resistance", "steering_lag", "input_delay", "tire_saturation"):
        assert name in names
    assert len(names) >= 8
    for name in names:
        e = get_effect(name)
        for q in e.params:
            assert q.unit and q.lower <= q.null <= q.upper and q.lower <= q.initial <= q.upper
    assert get_effect("steering_lag").state_names == ("delta_wheel",)


def test_fit_percent_and_noise_estimate():
    y = np.sin(np.linspace(0, 10, 500))
    assert fit_percent(y, y) == pytest.approx(100.0)
    assert fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0)
    rng = np.random.default_rng(0)
    noisy = y + 0.01 * rng.standard_normal(y.size)
    assert robust_noise_sigma(noisy) == pytest.approx(0.01, rel=0.15)


def test_contexts_get_their_own_friction(clean_df):
    df = clean_df.copy()
    df["terrain"] = np.where(df["t"] < 15.0, "asphalt", "gravel")
    data = prepare(df, "two", min_duration_s=10.0)
    model = WorkbenchModel(contexts=data.context_names)
    assert model.param_names == ["mu[asphalt]", "mu[gravel]"]


def test_low_sample_rate_rollouts_stay_stable(monkeypatch):
    """At 5 Hz one RK4 step would be unstable for the yaw/slip modes (h |lambda| ~ 9 at
    5 m/s); the model takes substeps from the eigenvalue bound and tracks the truth."""
    df = synth.simulate_truths([synth.Truth()], duration_s=30.0, rate_hz=5.0, noise=None)[0]
    data = prepare(df, "5 Hz", min_duration_s=10.0)
    model = WorkbenchModel()
    starts = window_starts(data, 10, 2, "all")
    err = model.errors(model.initial_theta(), data, starts, 10)
    assert np.max(np.abs(err[:, :, 5])) < 5e-3  # yaw rate [rad/s], amplitude ~0.5
    assert np.max(np.abs(err[:, :, 3])) < 1e-6  # speed [m/s]
    # one RK4 step per sample diverges
    import pcvfe_drake.models.model as model_module

    monkeypatch.setattr(model_module, "RK4_STABLE_HLAMBDA", 1e6)
    with np.errstate(all="ignore"):
        err1 = model.errors(model.initial_theta(), data, starts, 10)
    assert not np.all(np.abs(err1[:, :, 5]) < 1.0)


def test_model_parameters_are_effect_parameters_with_their_origin():
    """One definition of a parameter: the model's entries are EffectParams (with their checks)
    plus the effect or context they come from."""
    from pcvfe_drake.models.model import ParamInfo

    model = WorkbenchModel(None, effects=["drag"])
    assert all(isinstance(p, EffectParam) for p in model.params)
    base, drag = model.params[0], model.params[-1]
    assert (base.name, base.effect, base.context) == ("mu", None, 0)
    assert (drag.name, drag.effect, drag.context) == ("drag.CdA", "drag", None)
    assert drag.unit == "m^2" and drag.description
    with pytest.raises(ValueError, match="outside"):
        ParamInfo("mu", "-", 0.1, 1.0, 2.0, 0.1, 1.0)
