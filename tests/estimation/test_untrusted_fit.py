"""A live single-track fit the fit-quality checks distrust is not identifiable, and the run's
summary says why (no confident wrong answer in the live table)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.fitting import fit_gauss_newton
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.runs.summary import _limit_flag
from pcvfe_drake.vehicle.params import ford_escort


@pytest.fixture(scope="module")
def drive():
    params = ford_escort()
    t, S, U = s_curve_drive(params, [0.45], duration_s=4.0, phase_rad=[0.0])
    return params, np.round(t, 6), S[0], U[0]


def _estimate(drive, fit):
    params, t, states, inputs = drive
    est = ContextEstimator(params, LiveFitConfig())
    for k in range(t.size):
        est.add_sample(t[k], states[k], inputs[k], [3])
    est.refit(float(t[-1]), fit=fit)
    return est.table().get(3)


def test_a_fit_the_quality_checks_distrust_is_not_identifiable(drive):
    trusted = _estimate(drive, fit_gauss_newton)
    assert trusted.fitted and trusted.identifiable and trusted.untrusted == ""
    assert abs(trusted.mu - 0.45) < 0.02

    def on_bound(*args, **kwargs):
        result = fit_gauss_newton(*args, **kwargs)
        return replace(result, quality={**result.quality, "at_bound": ["mu"]})

    distrusted = _estimate(drive, on_bound)
    assert distrusted.fitted and distrusted.near_limit
    assert not distrusted.identifiable and distrusted.untrusted == "mu on its bound"
    assert distrusted.to_dict()["untrusted"] == "mu on its bound"
    flag = _limit_flag(
        {
            "fitted": True,
            "near_limit": True,
            "identifiable": False,
            **{"untrusted": distrusted.untrusted},
        }
    )
    assert flag == "fit not trustworthy: mu on its bound (not identifiable)"
    assert _limit_flag({"fitted": True, "near_limit": True, "identifiable": True}) == "near"
