"""Friction fitting with the workbench's effect model (estimation/effect_fit.py): parsing,
the controller's theta, the used-friction lower bound, planted-parameter recovery online, the
estimator's effect path and identifiability, and ``pcvfe fit --effects`` = ``pcvfe diagnose
--add`` on the same log."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.effect_fit import (
    EffectFitter,
    build_model,
    controller_theta,
    friction_used,
    small_slip_stiffness,
)
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.sample_store import inputs_as_read
from pcvfe_drake.handing.config import HandingConfig, LowerBound
from pcvfe_drake.models.effect_model import EffectModel, FitterEffect, parse_effects
from pcvfe_drake.runs.drivelog import write_drive_log
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth

STATES = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]


def arrays(df):
    return df["t"].to_numpy(), df[STATES].to_numpy(), df[["steer_rate", "accel"]].to_numpy()


@pytest.fixture(scope="module")
def saturating_log():
    """40 s at 50 Hz of a brush-tyre truth: stiffness mu 0.8, peak 0.7 (survey-grade noise)."""
    truth = synth.Truth(mu=0.8, mu_peak=0.7)
    return synth.simulate_truths([truth], duration_s=40.0, rate_hz=50.0, seed=1, substeps=2)[0]


def test_parse_effects_forms_and_errors():
    specs = parse_effects(
        [
            "tire_saturation",
            "steering_lag:tau=0.15",
            {"name": "drag", "fixed": {"CdA": 0.7}},
            FitterEffect("rolling_resistance"),
        ]
    )
    assert [s.name for s in specs] == [
        "tire_saturation",
        "steering_lag",
        "drag",
        "rolling_resistance",
    ]
    assert specs[1].fixed == {"tau": 0.15} and specs[2].fixed == {"CdA": 0.7}
    with pytest.raises(ValueError, match="unknown effect 'nope'"):
        parse_effects(["nope"])
    with pytest.raises(ValueError, match="no parameter 'k'"):
        parse_effects(["steering_lag:k=1"])
    with pytest.raises(ValueError, match="outside its bounds"):
        parse_effects(["steering_lag:tau=-3"])
    with pytest.raises(ValueError, match="param=value"):
        parse_effects(["steering_lag:tau"])
    with pytest.raises(ValueError, match="HandingConfig.unidentified"):
        LiveFitConfig(handing=HandingConfig(unidentified="maybe"))


def test_controller_theta_keeps_the_small_slip_stiffness():
    vp = ford_escort()
    for effects in ([], ["tire_saturation"], ["steering_lag", "drag"]):
        model, _, theta = build_model(vp, effects)
        theta[0] = 0.55
        k = small_slip_stiffness(model, theta)
        # the linear tyre (and a brush tyre at small slip) has mu C_S per unit load
        np.testing.assert_allclose(k, 0.55 * np.array([vp.C_Sf, vp.C_Sr]), rtol=1e-3)
        th = controller_theta(model, theta)
        assert th[0] == pytest.approx(0.55)
        np.testing.assert_allclose(th[0] * th[1:], k, rtol=1e-12)


def test_peak_tyre_theta_is_the_peak_with_the_fitted_stiffness():
    vp = ford_escort()
    # k_s = 0: the small-slip stiffness stays the nominal mu's, whatever the peak
    model, fixed, theta = build_model(vp, ["peak_tyre:k_s=0"])
    assert fixed.tolist() == [False, True]
    theta[0] = 0.45
    th = controller_theta(model, theta)
    assert th[0] == 0.45
    np.testing.assert_allclose(th[1:], np.array([vp.C_Sf, vp.C_Sr]) * vp.mu / 0.45, rtol=1e-3)
    # k_s = 1: stiffness proportional to the peak, the ST model's own parametrisation
    model, _, theta = build_model(vp, ["peak_tyre:k_s=1"])
    theta[0] = 0.45
    np.testing.assert_allclose(controller_theta(model, theta)[1:], [vp.C_Sf, vp.C_Sr], rtol=1e-3)


def test_friction_used_is_the_acceleration_quantile():
    t = np.arange(0.0, 10.0, 0.01)
    x = np.zeros((t.size, 7))
    x[:, 3] = 10.0
    x[:, 5] = 0.5 * (t > 5.0)  # 5 m/s^2 lateral in the second half
    used = friction_used(t, x)
    assert used == pytest.approx(5.0 / 9.81, rel=1e-6)
    assert friction_used(t, x, quantile=0.3) == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(friction_used(t[:5], x[:5]))


def test_online_effect_fit_recovers_planted_peak_and_mu(saturating_log):
    vp = ford_escort()
    t, S, U = arrays(saturating_log)
    cold = EffectFitter(vp, ["tire_saturation"], max_iterations=30)(t, S, U)
    values = dict(zip(cold.param_names, cold.model_theta, strict=True))
    assert cold.converged
    assert values["tire_saturation.mu_peak"] == pytest.approx(0.7, abs=0.03)
    assert values["mu"] == pytest.approx(0.8, abs=0.03)
    assert 0 < cold.std[0] < 0.03
    # the bare ST model reads the saturation as a lower mu (the bias the effect removes)
    bare = EffectFitter(vp, [], max_iterations=30)(t, S, U)
    assert bare.theta[0] < 0.8 - 0.1
    # fixing the peak at its diagnosed value: mu alone is fitted
    fixed = EffectFitter(vp, ["tire_saturation:mu_peak=0.7"], max_iterations=30)(t, S, U)
    assert fixed.model_theta[1] == 0.7 and np.isnan(fixed.model_std[1])
    assert fixed.theta[0] == pytest.approx(0.8, abs=0.03)
    # a warm refit from the converged vector takes at most one step
    warm = EffectFitter(vp, ["tire_saturation"], max_iterations=5)(
        t, S, U, previous=cold.model_theta
    )
    assert warm.iterations <= 2
    np.testing.assert_allclose(warm.model_theta, cold.model_theta, rtol=1e-3)
    assert EffectFitter(vp, ["drag"])(t[:30], S[:30], U[:30]) is None  # too few windows


def test_estimator_effect_path_and_lower_bound(saturating_log):
    vp = ford_escort()
    t, S, U = arrays(saturating_log)

    def run(**cfg):
        est = ContextEstimator(
            vp,
            LiveFitConfig(
                model=EffectModel(effects=["tire_saturation"]), sample_period_s=0.02, **cfg
            ),
        )
        read = inputs_as_read(U)  # a sample reads the input applied before it
        for k in range(t.size):
            est.add_sample(t[k], S[k], read[k], 0)
        est.refit(float(t[-1]))
        return est

    est = run()
    entry = est.table().get(0)
    assert entry.fitted and entry.status in ("fitted", "fitting")
    names = [n for n, _, _ in entry.model_params]
    assert names == ["mu", "tire_saturation.mu_peak"]
    assert entry.mu == pytest.approx(0.8, abs=0.05)
    assert entry.mu_lower_bound == pytest.approx(friction_used(t, S), rel=1e-9)
    assert 0.3 < entry.mu_lower_bound < 0.7  # below the peak it drove under
    d = est.table().to_dict()["entries"][0]
    assert set(d["model_params"]) == {"mu", "tire_saturation.mu_peak"}
    assert {"mu_lower_bound", "near_limit", "identifiable", "mu_is_peak"} <= set(d)
    np.testing.assert_allclose(est.theta_for(0), entry.theta)
    # lower_bound: a context whose mu is not identifiable hands the controller the bound,
    # keeping mu * C_S (the small-slip stiffness)
    strict = run(handing=HandingConfig(unidentified=LowerBound()), identifiable_std=1e-9)
    e2 = strict.table().get(0)
    assert not e2.identifiable
    th = strict.theta_for(0)
    assert th[0] == pytest.approx(max(e2.mu_lower_bound, 0.3))
    np.testing.assert_allclose(th[0] * th[1:], e2.mu * np.array(e2.theta[1:]), rtol=1e-9)
    loose = run(handing=HandingConfig(unidentified=LowerBound()), near_limit_fraction=0.1)
    assert loose.table().get(0).identifiable
    np.testing.assert_allclose(loose.theta_for(0), loose.table().get(0).theta)


def test_fit_effects_equals_diagnose_add(tmp_path, capsys, saturating_log):
    path = tmp_path / "drive.csv"
    write_drive_log(saturating_log, path)
    main(["diagnose", str(path), "--add", "tire_saturation", "--candidates", "drag", "--json"])
    diag = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["added"]["params"]
    args = ["fit", str(path), "--effects", "tire_saturation", "--json"]
    assert main([*args, "--covariance", "iid"]) == 0
    fit = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(fit["params"]) == set(diag)
    for name, p in diag.items():
        assert fit["params"][name]["value"] == pytest.approx(p["value"], rel=1e-9), name
        assert fit["params"][name]["std"] == pytest.approx(p["std"], rel=1e-9), name
    assert fit["params"]["tire_saturation.mu_peak"]["value"] == pytest.approx(0.7, abs=0.03)
    ctx = fit["contexts"]["all"]
    assert ctx["theta"]["mu"] == pytest.approx(fit["params"]["mu"]["value"])
    assert ctx["mu_lower_bound"] > 0.3
    # default: the same parameters, the std from the Newey-West sandwich (docs/fitting.md)
    assert main(args) == 0
    hac = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert hac["covariance"] == "hac" and fit["covariance"] == "iid"
    for name, p in diag.items():
        assert hac["params"][name]["value"] == pytest.approx(p["value"], rel=1e-9), name
    std = hac["contexts"]["all"]["mu_std"]
    assert 0 < std < 0.1 and std != pytest.approx(ctx["mu_std"], rel=1e-3)
    lo, hi = hac["contexts"]["all"]["mu_interval_95"]
    assert hac["contexts"]["all"]["near_limit"]
    assert lo == pytest.approx(ctx["theta"]["mu"] - 1.959964 * std)
    assert hi == pytest.approx(ctx["theta"]["mu"] + 1.959964 * std)
    # the table form runs and names the effect
    assert main(["fit", str(path), "--effects", "tire_saturation:mu_peak=0.7"]) == 0
    out = capsys.readouterr().out
    assert "tire_saturation (mu_peak=0.7)" in out and "all" in out


def test_mu_figure_draws_the_lower_bounds(tmp_path):
    import pandas as pd

    from pcvfe_drake.runs.figures import figure_mu_over_time

    t = np.arange(0.0, 20.0, 0.1)
    log = pd.DataFrame(
        {
            "t": t,
            "context": (t > 10).astype(int),
            "mu_true": np.where(t > 10, 0.45, 0.6),
            "mu_hat": np.where(t > 10, 0.5, 0.62),
        }
    )
    summary = {
        "mu_estimates": [
            {"id": 0, "majority_terrain": "concrete", "mu_lower_bound": 0.41, "near_limit": True},
            {"id": 1, "majority_terrain": "sand", "mu_lower_bound": 0.2, "near_limit": False},
        ]
    }
    path = figure_mu_over_time(log, tmp_path / "fig5.png", summary=summary)
    assert path.stat().st_size > 1000
