"""The workbench's residual tests hold their stated rate on residuals of a perfect model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from pcvfe_drake.workbench.evidence import lagged_corr, ma1_portmanteau, weighted_chi2_sf


@pytest.mark.parametrize("x", [2.0, 9.0, 20.0, 40.0])
def test_weighted_chi2_with_equal_weights_is_chi2(x):
    assert weighted_chi2_sf(x, np.ones(9)) == pytest.approx(chi2.sf(x, 9), rel=0.02)


def test_weighted_chi2_matches_a_simulated_tail():
    rng = np.random.default_rng(0)
    w = np.array([2.6, 1.9, 1.1, 0.5, 0.2, 0.05])
    draws = (rng.standard_normal((400_000, w.size)) ** 2) @ w
    for x in (np.quantile(draws, 0.9), np.quantile(draws, 0.999)):
        assert weighted_chi2_sf(x, w) == pytest.approx(np.mean(draws > x), rel=0.1)
    assert weighted_chi2_sf(0.0, w) == 1.0
    assert weighted_chi2_sf(1e6, w) < 1e-100


def _portmanteau_rates(n: int, max_lag: int, draws: int, seed: int):
    """p-values of the MA(1) test and of the plain chi-square on differenced white noise (the
    residual of a state the model integrates: lag-1 autocorrelation -0.5)."""
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((draws, n + 1))
    r = noise[:, 1:] - noise[:, :-1]
    p_new, p_chi2 = [], []
    for row in r:
        acf = lagged_corr(row, row, max_lag)[1:]
        q, p = ma1_portmanteau(acf, n)
        p_new.append(p)
        p_chi2.append(chi2.sf(q, max_lag - 1))
    return np.array(p_new), np.array(p_chi2)


def test_ma1_portmanteau_holds_its_rate_where_the_chi2_does_not():
    p_new, p_chi2 = _portmanteau_rates(n=150, max_lag=10, draws=4000, seed=1)
    # nominal 1 %: the MA(1) null distribution holds it (binomial sd 0.16 %), the chi-square
    # with K - 1 degrees of freedom (lags treated as independent) is ~2.5x too often
    assert np.mean(p_new < 0.01) < 0.016
    assert np.mean(p_new < 0.05) == pytest.approx(0.05, abs=0.015)
    assert np.mean(p_chi2 < 0.01) > 0.018


def test_ma1_portmanteau_detects_an_autocorrelated_residual():
    rng = np.random.default_rng(2)
    e = rng.standard_normal(400)
    r = np.convolve(e, np.ones(4) / 2.0, mode="valid")  # MA(3): lags 2 and 3 nonzero
    _, p = ma1_portmanteau(lagged_corr(r, r, 10)[1:], r.size)
    assert p < 1e-6
