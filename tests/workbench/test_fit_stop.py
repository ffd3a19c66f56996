"""The loop's stopping rule for a fit: the Gauss-Newton gain it checks before it stops early."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.models.estimate import FitResult
from pcvfe_drake.workbench.ranking import DiagnoseConfig, gauss_newton_gain


class _Bounded:
    """The part of a model ``gauss_newton_gain`` reads: its bounds."""

    def __init__(self, lo, hi):
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)

    def bounds(self):
        return self.lo, self.hi


def _linear(theta, lo=(-10.0, -10.0), hi=(10.0, 10.0)):
    """Residuals r = J (theta - theta*) + e of a linear problem (e orthogonal to J), at
    ``theta``, with theta* = (1, 2): the Gauss-Newton step reaches theta* exactly."""
    rng = np.random.default_rng(0)
    jac = rng.standard_normal((200, 2))
    e = rng.standard_normal(200)
    e -= jac @ np.linalg.lstsq(jac, e, rcond=None)[0]
    d = np.asarray(theta, float) - np.array([1.0, 2.0])
    r = jac @ d + e
    res = FitResult(
        _Bounded(lo, hi), np.asarray(theta, float), np.zeros(2), float(r @ r), r.size, 50.0, 1,
        True, residuals=r, jacobian=jac,
    )  # fmt: skip
    return res, float((jac @ d) @ (jac @ d)), float(e @ e)


def test_gain_is_the_likelihood_ratio_of_the_gauss_newton_step():
    res, decrease, _ = _linear([1.3, 1.5])
    assert gauss_newton_gain(res) == pytest.approx(50.0 * decrease / res.cost, rel=1e-9)
    at_min, _, _ = _linear([1.0, 2.0])
    assert gauss_newton_gain(at_min) < 1e-12
    # no Jacobian kept: nothing is promised to be small
    assert gauss_newton_gain(FitResult(res.model, res.theta, res.std, 1.0, 1, 1.0, 1, True)) == (
        np.inf
    )


def test_a_parameter_held_by_its_bound_promises_nothing():
    """theta* = (1, 2) lies beyond the upper bound 1.5 of the second parameter: at (1.2, 1.5)
    the step would push it out, so what is promised is the first parameter's step alone."""
    res, _, _ = _linear([1.2, 1.5], hi=(10.0, 1.5))
    j1, r = res.jacobian[:, 0], res.residuals
    alone = 50.0 * float(j1 @ r) ** 2 / float(j1 @ j1) / res.cost
    assert gauss_newton_gain(res) == pytest.approx(alone, rel=1e-9)
    free, _, _ = _linear([1.2, 1.5])
    assert gauss_newton_gain(free) > 5 * alone  # without the bound, theta* is promised


def test_the_default_stops_at_a_hundredth_of_the_statistic():
    assert DiagnoseConfig().lr_tol == 0.01
