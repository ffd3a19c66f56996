"""Exploration for contexts whose friction peak is not identifiable (``unidentified_mu: probe``):
the policy's steps, its bounds and back-off on a synthetic context, the saturation signs, the
estimator's use of it, and the impossible case of a peak fitted below the used friction."""

from dataclasses import replace

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator, LiveFitConfig
from pcvfe_drake.estimation.effect_fit import friction_used
from pcvfe_drake.estimation.probe import ProbeState, axle_slip_angles, probe_step, saturated
from pcvfe_drake.vehicle.params import ford_escort

RULES = dict(step_rel=0.1, hold_s=3.0, max_excess=0.08, use_fraction=0.64)


def _step(state, t, lb, sat=False, prior=1.05, floor=0.3):
    return probe_step(
        state, t, lower_bound=lb, floor_mu=floor, prior_mu=prior, is_saturated=sat, **RULES
    )


def test_probe_starts_at_the_lower_bound_value_and_rises_in_bounded_steps():
    s = _step(ProbeState(), 0.0, lb=0.2)
    assert s.mu == pytest.approx(0.3) and s.steps == 0  # max(bound, floor)
    assert _step(s, 2.9, lb=0.2) is s  # holds for hold_s
    s = _step(s, 3.0, lb=0.2)
    assert s.mu == pytest.approx(0.33) and s.steps == 1  # +10 %
    for t in (6.0, 9.0, 12.0, 15.0, 18.0):
        s = _step(s, t, lb=0.2)
    # the planner is never asked for more than 0.08 above the demonstrated 0.2: 0.28 / 0.64
    assert s.mu == pytest.approx(0.28 / 0.64)
    steps = s.steps
    assert _step(s, 21.0, lb=0.2).mu == s.mu and _step(s, 21.0, lb=0.2).steps == steps
    # the car used more: the bound moves up and the probe with it, one step at a time
    s2 = _step(s, 21.0, lb=0.3)
    assert s2.mu == pytest.approx(s.mu * 1.1)
    # never above the prior
    high = ProbeState(mu=1.0, last_step_s=0.0)
    assert _step(high, 3.0, lb=0.9).mu == pytest.approx(1.05)


def test_probe_backs_off_on_saturation_and_keeps_below_the_ceiling():
    s = ProbeState(mu=0.5, last_step_s=0.0, steps=3)
    b = _step(s, 1.0, lb=0.35, sat=True)  # at once, no hold
    assert b.mu == pytest.approx(0.5 / 1.21) and b.ceiling == pytest.approx(0.5 / 1.1)
    assert b.backoffs == 1 and b.last_step_s == 1.0
    later = b
    for t in np.arange(4.0, 60.0, 3.0):
        later = _step(later, float(t), lb=0.6)
    assert later.mu == pytest.approx(0.5 / 1.1)  # back up to the ceiling, not above


def test_probe_on_a_synthetic_context_rises_stops_and_backs_off():
    """A car that uses the planner's share of the handed mu; its tyres show saturation (large
    slip) when that demand exceeds 85 % of the true peak."""

    def drive(peak, prior=1.05, seconds=200):
        s, lb, history, used_max = ProbeState(), 0.2, [], 0.0
        for t in np.arange(0.0, seconds, 1.0):
            demand = 0.64 * (s.mu if s.started else 0.3)
            used = min(demand, 0.95 * peak)
            used_max = max(used_max, used)
            lb = max(lb, used)
            s = _step(s, float(t), lb=lb, sat=demand > 0.85 * peak, prior=prior)
            history.append(s.mu)
        return s, np.array(history), used_max

    s, mu, used = drive(peak=0.6)
    ratios = mu[1:] / mu[:-1]
    assert np.all(ratios <= 1.1 + 1e-12)  # bounded steps
    assert s.backoffs >= 1  # it found the limit and backed off
    assert used <= 0.95 * 0.6 and mu.max() < 0.6 / 0.64 * 1.1  # at most one step beyond
    # it settles below the saturating demand, above where it started
    assert 0.3 < mu[-1] <= 0.85 * 0.6 / 0.64
    # a terrain above the prior: it rises to the prior and stops there, no saturation
    s, mu, _ = drive(peak=2.0)
    assert s.backoffs == 0 and mu[-1] == pytest.approx(1.05) and mu.max() <= 1.05


def test_saturation_signs_from_slip_angles():
    vp = ford_escort()
    n = 50
    x = np.zeros((n, 7))
    x[:, 3] = 8.0
    x[:, 2] = 0.05  # steady cornering, kinematic: psi_dot = v delta / L, beta = lr/L delta
    L = vp.lf + vp.lr
    x[:, 5] = 8.0 * 0.05 / L
    x[:, 6] = vp.lr / L * 0.05
    af, ar = axle_slip_angles(x, vp.lf, vp.lr)
    assert np.all(np.abs(af) < 2e-3) and np.all(np.abs(ar) < 2e-3)
    assert not saturated(x, vp.lf, vp.lr, 0.035)
    slide = x.copy()
    slide[:, 6] -= 0.08  # the rear lets go: side slip
    assert saturated(slide, vp.lf, vp.lr, 0.035)
    push = x.copy()
    push[:, 5] *= 0.3  # the front lets go: yaw rate far short of the steering's
    push[:, 6] = vp.lr * push[:, 5] / 8.0  # rear at zero slip
    assert saturated(push, vp.lf, vp.lr, 0.035)
    slow = slide.copy()
    slow[:, 3] = 1.0  # below 2 m/s: not judged
    assert not saturated(slow, vp.lf, vp.lr, 0.035)
    one = x.copy()
    one[-1, 6] -= 0.3  # a single wild sample does not count
    assert not saturated(one, vp.lf, vp.lr, 0.035)


def _fitted_estimator(**cfg):
    params = ford_escort()
    est = ContextEstimator(
        params, LiveFitConfig(unidentified_mu="probe", sample_period_s=0.02, **cfg)
    )
    est.add_sample(0.0, np.array([0, 0, 0, 8.0, 0, 0, 0]), [0, 0], [0])
    slot = est._slots[0]
    slot.estimate = replace(
        slot.estimate,
        theta=(1.5, params.C_Sf, params.C_Sr),
        theta_std=(0.5, np.nan, np.nan),
        fits=1,
        mu_lower_bound=0.2,
    )
    return est, slot


def _feed(est, t0, t1, beta=0.0):
    for t in np.arange(t0, t1, 0.02):
        est.add_sample(float(t), np.array([0, 0, 0, 8.0, 0, 0, beta]), [0, 0], [0])


def test_estimator_probes_a_not_identifiable_context_and_backs_off():
    est, slot = _fitted_estimator()
    th0 = est.theta_for()
    assert th0[0] == pytest.approx(0.3)  # before the first update: the lower bound's value
    np.testing.assert_allclose(th0[0] * th0[1:], 1.5 * np.array(slot.estimate.theta[1:]))
    mus = []
    for k in range(8):
        _feed(est, 0.02 + 3.0 * k, 3.0 * (k + 1))
        est.update_probe(3.0 * (k + 1))
        mus.append(est.theta_for()[0])
    assert mus[0] == pytest.approx(0.3) and mus[1] == pytest.approx(0.33)
    assert mus[-1] == pytest.approx(0.28 / 0.64)  # bounded by the demonstrated 0.2
    # the rear slides: back off at once
    _feed(est, 24.02, 24.6, beta=0.1)
    est.update_probe(24.6)
    assert est.theta_for()[0] == pytest.approx(0.28 / 0.64 / 1.21)
    entry = est.table().get(0)
    assert entry.probe.backoffs == 1 and entry.probe.ceiling == pytest.approx(0.28 / 0.64 / 1.1)
    assert est.table().to_dict()["entries"][0]["probe"]["backoffs"] == 1
    # identifiable: the estimate takes over, the probe stays where it was
    slot.estimate = replace(
        slot.estimate, theta=(0.55, *slot.estimate.theta[1:]), identifiable=True
    )
    assert est.theta_for()[0] == 0.55
    # never above the upper end of a not identifiable estimate's 95 % interval
    slot.estimate = replace(
        slot.estimate,
        theta=(0.32, *slot.estimate.theta[1:]),
        theta_std=(0.01, np.nan, np.nan),
        identifiable=False,
    )
    assert est.theta_for()[0] == pytest.approx(0.32 + 1.96 * 0.01)


def test_probe_settings_are_checked():
    with pytest.raises(ValueError, match="probe_use_fraction"):
        LiveFitConfig(probe_use_fraction=1.5)
    with pytest.raises(ValueError, match="probe_hold_s"):
        LiveFitConfig(probe_hold_s=0.0)
    assert "probe" in repr(LiveFitConfig(unidentified_mu="probe"))


def test_peak_below_the_used_friction_is_raised_to_it():
    """A fitted peak below the friction the car used is impossible: the controller gets the
    used friction (the smallest peak the data allow), stiffness kept, and it is not
    identifiable."""
    params = ford_escort()
    est = ContextEstimator(params, LiveFitConfig())
    est.add_sample(0.0, np.array([0, 0, 0, 8.0, 0, 0, 0]), [0, 0], [0])
    slot = est._slots[0]
    slot.estimate = replace(
        slot.estimate,
        theta=(0.2, 50.0, 60.0),
        theta_std=(0.01, np.nan, np.nan),
        fits=1,
        mu_lower_bound=0.25,
        below_used=True,
        mu_is_peak=True,
    )
    th = est.theta_for(0)
    assert th[0] == pytest.approx(0.25)
    np.testing.assert_allclose(th[0] * th[1:], 0.2 * np.array([50.0, 60.0]))


def test_identifiability_flags_a_peak_below_the_lateral_friction_used():
    est = ContextEstimator(ford_escort(), LiveFitConfig())
    t = np.arange(0.0, 10.0, 0.01)
    x = np.zeros((t.size, 7))
    x[:, 3] = 10.0
    x[:, 5] = 0.3  # a_y = 3 m/s^2
    x[:, 3] += 2.0 * t  # and a_x = 2 m/s^2: a lateral peak is bounded by a_y alone
    x[:, 5] = 3.0 / x[:, 3]
    empty = est._slot(0).estimate
    peak = est._identifiability(empty, t, x, 0.25, 0.01, peak=True)
    assert peak["mu_lower_bound"] == pytest.approx(3.0 / 9.81, rel=1e-6)
    assert peak["mu_lower_bound"] == pytest.approx(friction_used(t, x, lateral_only=True))
    assert peak["below_used"] and not peak["identifiable"]
    st = est._identifiability(empty, t, x, 0.25, 0.01, peak=False)
    assert st["mu_lower_bound"] == pytest.approx(np.hypot(3.0, 2.0) / 9.81, rel=1e-6)
    assert not st["below_used"]  # the ST fit's mu is not a peak


def test_peak_slip_is_the_peak_tyres_and_limits_are_per_axle():
    from pcvfe_drake.estimation.probe import MF_SHAPE, peak_slip_rad
    from pcvfe_drake.workbench.tyre_effects import MF_SHAPE as PEAK_TYRE_SHAPE

    assert MF_SHAPE == PEAK_TYRE_SHAPE
    k = 21.92
    a = float(peak_slip_rad(0.3, k))
    assert a == pytest.approx(0.043, abs=5e-4)
    # the magic formula with that stiffness and peak is at its largest there
    alphas = np.linspace(0.0, 3 * a, 3001)
    force = 0.3 * np.sin(MF_SHAPE * np.arctan(k * alphas / (MF_SHAPE * 0.3)))
    assert alphas[np.argmax(force)] == pytest.approx(a, rel=2e-3)
    vp = ford_escort()
    x = np.zeros((30, 7))
    x[:, 3] = 8.0
    x[:, 6] = -0.03  # rear slip 0.03 rad, front 0.03 rad
    assert saturated(x, vp.lf, vp.lr, (0.05, 0.02))
    assert not saturated(x, vp.lf, vp.lr, (0.05, 0.04))


def test_back_offs_never_go_below_the_start_nor_judge_noise():
    # repeated saturation at the start level: it stays there (a ratchet to nothing otherwise)
    s = _step(ProbeState(), 0.0, lb=0.2)
    for t in range(1, 30):
        s = _step(s, float(t), lb=0.2, sat=True)
    assert s.mu == pytest.approx(0.3) and s.ceiling == pytest.approx(0.3)
    # a slip limit below the measurement noise is raised to the noise floor
    from pcvfe_drake.estimation.probe import MIN_SLIP_LIMIT_RAD

    vp = ford_escort()
    rng = np.random.default_rng(0)
    x = np.zeros((100, 7))
    x[:, 3] = 5.0
    x[:, 6] = rng.normal(0.0, 0.005, 100)  # INS side-slip noise only
    assert not saturated(x, vp.lf, vp.lr, 0.002)
    x[:, 6] += 2 * MIN_SLIP_LIMIT_RAD
    assert saturated(x, vp.lf, vp.lr, 0.002)
