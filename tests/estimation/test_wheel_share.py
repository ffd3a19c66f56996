"""Identifiability judged by the data and by the tyres: ``probe.wheel_peak_share`` (how near the
most-used wheel came to its peak, each wheel at its own slip) and the estimator's test on the
std without the model-error budget."""

import math

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.effect_fit import identifiability
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.probe import MF_SHAPE, axle_slip_angles, wheel_peak_share
from pcvfe_drake.models.chassis_effects import wheel_slip_offsets
from pcvfe_drake.models.effect_model import EffectModel
from pcvfe_drake.vehicle.params import ford_escort

VP = ford_escort()
STIFFNESS = np.array([21.9, 25.9])  # mu * C_S per axle [1/rad], per load


def steady_bend(v=4.7, delta=0.21, r=0.40, front_slip=0.0145, n=100):
    """A slow tight bend of the slalom, held (the multi-body lap's numbers, front_axle_gap: the
    single-track front slip 0.0145 rad); the side slip is the one that gives ``front_slip``."""
    beta = math.asin(math.tan(delta - front_slip) - VP.lf * r / v)
    t = np.arange(n) * 0.01
    x = np.tile([0.0, 0.0, delta, v, 0.0, r, beta], (n, 1))
    return t, x


def curve_share(slip, mu, k):
    return math.sin(min(MF_SHAPE * math.atan(k * abs(slip) / (MF_SHAPE * mu)), math.pi / 2))


def test_without_a_track_it_is_the_axles_place_on_the_curve():
    t, x = steady_bend()
    af, ar = (a[0] for a in axle_slip_angles(x[:1], VP.lf, VP.lr))
    expected = max(curve_share(af, 0.45, STIFFNESS[0]), curve_share(ar, 0.45, STIFFNESS[1]))
    assert wheel_peak_share(t, x, VP, 0.45, STIFFNESS, 0.0) == pytest.approx(expected)


def test_the_track_puts_the_inner_front_wheel_nearer_its_peak():
    t, x = steady_bend()
    axle = wheel_peak_share(t, x, VP, 0.45, STIFFNESS, 0.0)
    wheels = wheel_peak_share(t, x, VP, 0.45, STIFFNESS, 1.39)
    af = axle_slip_angles(x[:1], VP.lf, VP.lr)[0][0]
    left, right = wheel_slip_offsets(x[:1], VP.lf, np.array([1.39]))
    inner = af + max(left[0], right[0])
    assert inner > af + 0.005  # the inner wheel works at a clearly larger slip
    assert wheels == pytest.approx(curve_share(inner, 0.45, STIFFNESS[0]))
    assert wheels > axle + 0.1


def test_a_higher_peak_reads_a_smaller_share_and_past_the_peak_it_is_one():
    t, x = steady_bend()
    shares = [wheel_peak_share(t, x, VP, mu, STIFFNESS, 1.39) for mu in (0.3, 0.45, 0.8, 1.2)]
    assert np.all(np.diff(shares) < 0)  # a peak fitted too high errs safe
    t, x = steady_bend(delta=0.4)
    assert wheel_peak_share(t, x, VP, 0.1, STIFFNESS, 1.39) == 1.0


def test_too_few_fast_samples_give_no_share():
    t, x = steady_bend(v=1.5)  # below MIN_SPEED_MPS: kinematic slip
    assert math.isnan(wheel_peak_share(t, x, VP, 0.45, STIFFNESS, 1.39))
    t, x = steady_bend(n=10)
    assert math.isnan(wheel_peak_share(t, x, VP, 0.45, STIFFNESS, 1.39))


def _straight_then_bends():
    """10 s whose lateral friction used is 0.153 (a_y = 1.5 m/s^2)."""
    t = np.arange(0.0, 10.0, 0.01)
    x = np.zeros((t.size, 7))
    x[:, 3] = 10.0
    x[:, 5] = 0.15
    return t, x


def test_a_wheel_near_its_peak_makes_a_peak_fit_near_the_limit():
    t, x = _straight_then_bends()
    args = (t, x, 0.45, 0.01, True, math.nan, 0.6, 0.05)
    assert not identifiability(*args)["near_limit"]  # used 0.153 < 0.6 * 0.45
    assert not identifiability(*args, wheel_share=0.55)["near_limit"]
    near = identifiability(*args, wheel_share=0.85)
    assert near["near_limit"] and near["identifiable"]
    assert near["mu_lower_bound"] == pytest.approx(1.5 / 9.81, rel=1e-6)  # the bound is unchanged
    st = identifiability(t, x, 0.45, 0.01, False, math.nan, 0.6, 0.05, wheel_share=0.85)
    assert not st["near_limit"]  # the single-track fit's mu is not a peak


def test_the_estimator_judges_the_std_without_the_model_error_budget():
    t, x = _straight_then_bends()
    mu, data_std = 0.22, 0.01  # near: used 0.153 >= 0.6 * 0.22
    for rel in (0.0, 0.11, 0.3):
        est = ContextEstimator(VP, LiveFitConfig(model=EffectModel(model_error_rel=rel)))
        empty = est._slot(0).estimate
        reported = math.hypot(data_std, rel * mu)  # what the fit reports with the budget
        assert est._identifiability(empty, t, x, mu, reported, True)["identifiable"]
    est = ContextEstimator(VP, LiveFitConfig(model=EffectModel(model_error_rel=0.11)))
    empty = est._slot(0).estimate
    assert not est._identifiability(empty, t, x, mu, math.hypot(0.06, 0.11 * mu), True)[
        "identifiable"
    ]  # the data alone leave 0.06


def test_without_model_error_inverts_with_model_error():
    from pcvfe_drake.estimation.fit_options import with_model_error, without_model_error

    for mu, std, rel in [(0.45, 0.01, 0.11), (0.8, 0.03, 0.26), (0.3, 0.02, 0.0)]:
        assert without_model_error(mu, with_model_error(mu, std, rel), rel) == pytest.approx(std)
    assert without_model_error(0.45, 0.01, 0.5) == 0.0  # the budget is all of it
    assert math.isinf(without_model_error(0.45, math.inf, 0.11))
