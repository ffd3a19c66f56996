"""The Newey-West sandwich covariance of the least-squares core (``least_squares.hac_covariance``)
and the intervals built on it (``ContextEstimate.mu_interval_95``, the summary's ``covered_95``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcvfe_drake.estimation.estimate_table import Z95, ContextEstimate
from pcvfe_drake.estimation.fit_uncertainty import hac_lag
from pcvfe_drake.models import least_squares as lsq


def _windows(n_windows, k, rng, rho=0.0, sigma=1.0, slope=0.5):
    """A straight line through the origin fitted on n_windows windows of k samples; regressor
    and noise are AR(1) with coefficient rho along time (windows in time order). Returns the
    estimate, the Jacobian and the residuals at the estimate."""
    n = n_windows * k

    def ar1():
        out = np.empty(n)
        out[0] = rng.normal()
        innov = rng.normal(size=n) * math.sqrt(1.0 - rho**2)
        for i in range(1, n):
            out[i] = rho * out[i - 1] + innov[i]
        return out

    x = ar1()  # the excitation varies slowly too (as a manoeuvre does)
    e = ar1() * sigma
    y = slope * x + e
    a = float(x @ y / (x @ x))
    J = x[:, None]
    r = a * x - y
    return a, J, r


def test_independent_residuals_give_the_gauss_newton_std():
    rng = np.random.default_rng(0)
    _, J, r = _windows(400, 10, rng)
    hac = math.sqrt(lsq.hac_covariance(J, r, 400, 3)[0, 0])
    iid = math.sqrt(lsq.covariance(J, float(r @ r))[0, 0])
    assert hac == pytest.approx(iid, rel=0.15)


def test_correlated_residuals_coverage():
    """Regressor and noise correlated over ~10 samples (2 windows): the independent-residual
    std is ~2.5x too small and its 95 % intervals cover the truth about half the time; the
    sandwich with a lag of a few windows covers it ~88 % of the time (Newey-West is somewhat
    optimistic on 100 windows)."""
    rng = np.random.default_rng(1)
    cover = {"iid": 0, "hac": 0}
    ratio = []
    n_rep = 200
    for _ in range(n_rep):
        a, J, r = _windows(100, 5, rng, rho=0.9)
        s_hac = math.sqrt(lsq.hac_covariance(J, r, 100, 4)[0, 0])
        s_iid = math.sqrt(lsq.covariance(J, float(r @ r))[0, 0])
        cover["hac"] += abs(a - 0.5) <= Z95 * s_hac
        cover["iid"] += abs(a - 0.5) <= Z95 * s_iid
        ratio.append(s_hac / s_iid)
    assert cover["hac"] / n_rep >= 0.84
    assert cover["iid"] / n_rep <= 0.6
    assert np.median(ratio) > 2.0


def test_model_error_widens_the_std():
    """A line fitted to a curve (model error, heteroscedastic residuals): the sandwich matches
    the scatter of the slope over repeated draws; the Gauss-Newton std does not."""
    rng = np.random.default_rng(2)
    est, s_hac, s_iid = [], [], []
    for _ in range(300):
        x = rng.uniform(0.0, 2.0, 400)
        y = x**3 + rng.normal(size=400) * 0.05
        a = float(x @ y / (x @ x))
        J = x[:, None]
        r = a * x - y
        est.append(a)
        s_hac.append(math.sqrt(lsq.hac_covariance(J, r, 400, 0)[0, 0]))
        s_iid.append(math.sqrt(lsq.covariance(J, float(r @ r))[0, 0]))
    scatter = float(np.std(est))
    assert np.median(s_hac) == pytest.approx(scatter, rel=0.2)
    assert np.median(s_iid) < 0.85 * scatter


def test_prior_and_uninformative_data():
    rng = np.random.default_rng(3)
    _, J, r = _windows(50, 4, rng)
    J2 = np.column_stack([J[:, 0], np.zeros(len(r))])  # the 2nd parameter has no data
    cov = lsq.hac_covariance(J2, r, 50, 2, prior_precision=np.array([0.0, 1.0 / 0.5**2]))
    assert math.sqrt(cov[1, 1]) == pytest.approx(0.5, rel=1e-6)
    assert cov[0, 0] > 0
    free = lsq.hac_covariance(J2, r, 50, 2, free=np.array([True, False]))
    assert free[1, 1] == 0.0 and free[0, 0] == pytest.approx(cov[0, 0], rel=1e-6)


def test_zero_residuals_and_bad_shapes():
    J = np.ones((20, 1))
    assert np.all(lsq.hac_covariance(J, np.zeros(20), 5, 2) == 0.0)
    with pytest.raises(ValueError, match="do not split into 3 windows"):
        lsq.hac_covariance(J, np.ones(20), 3, 1)


def test_hac_lag_in_windows():
    t0 = np.arange(0.0, 10.0, 0.05)  # one window every 0.05 s
    assert hac_lag(t0, 0.1, 2.0) == 42  # windows starting within 0.1 s + 2 s
    assert hac_lag(np.arange(0.0, 50.0, 0.5), 1.0, 2.0) == 6
    assert hac_lag(None, 0.1, 2.0) == 1


def _entry(**kw):
    base = dict(context_id=0, theta=(0.5, 20.0, 20.0), theta_std=(0.02, math.nan, math.nan))
    base.update(fits=1, mu_lower_bound=0.4, near_limit=True)
    base.update(kw)
    return ContextEstimate(**base)


def test_interval_is_two_sided_near_the_limit_one_sided_otherwise():
    lo, hi = _entry().mu_interval_95
    assert lo == pytest.approx(0.5 - Z95 * 0.02) and hi == pytest.approx(0.5 + Z95 * 0.02)
    far = _entry(mu_lower_bound=0.2, near_limit=False, theta=(1.7, 20.0, 20.0))
    assert far.mu_interval_95 == (0.2, math.inf)
    assert far.to_dict()["mu_interval_95"] == [0.2, None]
    assert all(math.isnan(v) for v in _entry(fits=0).mu_interval_95)


def test_summary_scores_the_table_interval():
    import pandas as pd

    from pcvfe_drake.runs.summary import mu_estimates

    t = np.arange(0.0, 30.0, 0.05)
    log = pd.DataFrame({"t": t, "context": 0, "terrain": "concrete", "mu_hat": 1.7, "mu_true": 0.6})
    table = [{"id": 0, "mu": 1.7, "mu_std": 0.5, "samples": 10, "mu_interval_95": [0.25, math.inf]}]
    (e,) = mu_estimates(log, {"concrete": 0.6}, estimate_table=table)
    assert e["covered_95"] is True and e["interval_95"] == [0.25, None]
    table[0]["mu_interval_95"] = [0.65, math.inf]  # the car used more than the truth: not
    (e,) = mu_estimates(log, {"concrete": 0.6}, estimate_table=table)
    assert e["covered_95"] is False
    del table[0]["mu_interval_95"]  # no interval in the table: mu +- 1.96 std
    (e,) = mu_estimates(log, {"concrete": 0.6}, estimate_table=table)
    assert e["covered_95"] is False and e["interval_95"][0] == pytest.approx(1.7 - Z95 * 0.5)


def test_st_fit_std_and_model_error_budget():
    """The ST fit on a correct model with the documented noise: over noise draws the sandwich's
    std matches the scatter of the estimate; the same theta as the Gauss-Newton std's fit; the
    model-error budget adds in quadrature."""
    from pcvfe_drake.estimation.fit_dataset import build_windows
    from pcvfe_drake.estimation.fit_options import FitOptions, with_model_error
    from pcvfe_drake.estimation.fitting import fit_gauss_newton
    from pcvfe_drake.models.synthetic_drive import s_curve_drive
    from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
    from pcvfe_drake.vehicle.params import ford_escort

    params = ford_escort()
    t, S, U = s_curve_drive(params, (0.8,), duration_s=15.0, phase_rad=[2.0])
    rng = np.random.default_rng(5)
    err, std = [], []
    for _ in range(8):
        data = build_windows(t, MeasurementNoise().apply(S[0], rng), U[0]).by_context[0]
        hac = fit_gauss_newton(data, params, None, FitOptions())
        err.append(hac.theta[0] - 0.8)
        std.append(hac.std[0])
    assert 0.6 * np.std(err) < np.median(std) < 1.6 * np.std(err)
    iid = fit_gauss_newton(data, params, None, FitOptions(covariance="iid"))
    budget = fit_gauss_newton(data, params, None, FitOptions(model_error_rel=0.1))
    assert hac.theta[0] == iid.theta[0] == budget.theta[0]
    assert budget.std[0] == pytest.approx(math.hypot(hac.std[0], 0.1 * hac.theta[0]))
    assert np.isnan(budget.std[1])  # only mu carries the budget (stiffnesses not fitted)
    assert with_model_error(0.5, math.inf, 0.2) == math.inf
    assert with_model_error(0.5, 0.01, 0.0) == 0.01


def test_bad_settings_are_refused():
    from pcvfe_drake.estimation.effect_fit import EffectFitter
    from pcvfe_drake.estimation.fit_options import FitOptions
    from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
    from pcvfe_drake.models.effect_model import EffectModel
    from pcvfe_drake.vehicle.params import ford_escort

    with pytest.raises(ValueError, match="covariance must be one of"):
        FitOptions(covariance="bootstrap")
    with pytest.raises(ValueError, match="model_error_rel must be >= 0"):
        FitOptions(model_error_rel=-0.1)
    with pytest.raises(ValueError, match="hac_lag_s"):
        FitOptions(hac_lag_s=math.nan)
    with pytest.raises(ValueError, match="EffectModel.model_error_rel"):
        LiveFitConfig(model=EffectModel(model_error_rel=math.inf))
    with pytest.raises(ValueError, match="EffectFitter.covariance"):
        EffectFitter(ford_escort(), ["peak_tyre"], covariance="x")
    with pytest.raises(ValueError, match="EffectFitter.model_error_rel"):
        EffectFitter(ford_escort(), ["peak_tyre"], model_error_rel=-1.0)
