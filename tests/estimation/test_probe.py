"""Exploration for contexts whose friction peak is not identifiable (``handing: !Probe``):
the policy's steps, its bounds and back-off on a synthetic context, the saturation signs, the
estimator's use of it, and the impossible case of a peak fitted below the used friction."""

import math
from dataclasses import replace

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.effect_fit import friction_used
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.probe import (
    ProbeSettings,
    ProbeState,
    axle_slip_angles,
    peak_slip_rad,
    probe_step,
    saturated,
)
from pcvfe_drake.handing.config import Conservative, HandingConfig, Probe, StatedFloor
from pcvfe_drake.handing.context_state import ContextHanding
from pcvfe_drake.vehicle.params import ford_escort

RULES = dict(step_rel=0.1, hold_s=3.0, max_excess=0.08, use_fraction=0.64)
SMALL_STEPS = Probe(max_excess=0.08, fast_step_rel=0.25)
"""The probe with a 25 % fast step and 0.08 of excess (the numbers below are worked for them)."""


def probing(floor_stated: bool = False, probe: Probe = SMALL_STEPS, **cfg) -> LiveFitConfig:
    """A fitter config whose handing probes (with a stated floor: the phase before the id too;
    no rise confirmation: these tests drive one context)."""
    unknown = StatedFloor() if floor_stated else Conservative()
    handing = HandingConfig(unknown=unknown, unidentified=probe, confirm_rise_s=0.0)
    return LiveFitConfig(handing=handing, **cfg)


def _times(x, dt=0.01):
    """Sample times [s] of the states ``x`` at the fitter's rate."""
    return np.arange(len(x)) * dt


def _probe(est, ident=0):
    return est.handing.contexts[ident].probe


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
    assert not saturated(_times(x), x, vp.lf, vp.lr, 0.035)
    slide = x.copy()
    slide[:, 6] -= 0.08  # the rear lets go: side slip
    assert saturated(_times(slide), slide, vp.lf, vp.lr, 0.035)
    push = x.copy()
    push[:, 5] *= 0.3  # the front lets go: yaw rate far short of the steering's
    push[:, 6] = vp.lr * push[:, 5] / 8.0  # rear at zero slip
    assert saturated(_times(push), push, vp.lf, vp.lr, 0.035)
    slow = slide.copy()
    slow[:, 3] = 1.0  # below 2 m/s: not judged
    assert not saturated(_times(slow), slow, vp.lf, vp.lr, 0.035)
    one = x.copy()
    one[-1, 6] -= 0.3  # a single wild sample does not count
    assert not saturated(_times(one), one, vp.lf, vp.lr, 0.035)


def test_saturation_reads_the_slips_through_the_ins_noise():
    # a low level on a grippy terrain: the car corners at 0.12 g on a tyre far from its peak;
    # one sample's INS noise (side slip 0.005 rad, yaw rate 0.01 rad/s) is as large as the
    # limit at a 0.19 level, the slips' 0.2 s mean is not
    vp = ford_escort()
    rng = np.random.default_rng(3)
    n, v, k = 100, 4.6, 21.9
    limit = 0.5 * peak_slip_rad(0.19, k)
    x = np.zeros((n, 7))
    x[:, 3] = v
    x[:, 5] = 0.12 * 9.81 / v
    x[:, 2] = (vp.lf + vp.lr) * x[:, 5] / v  # a neutral car: both axles at the same slip
    x[:, 6] = vp.lr * x[:, 5] / v - 0.12 / k  # that slip: the linear tyre's at 0.12 g
    assert np.allclose(axle_slip_angles(x, vp.lf, vp.lr), 0.12 / k, rtol=0.1)
    noisy = x.copy()
    noisy[:, 6] += rng.normal(0.0, 0.005, n)
    noisy[:, 5] += rng.normal(0.0, 0.01, n)
    af, ar = axle_slip_angles(noisy, vp.lf, vp.lr)
    raw = max(np.quantile(np.abs(af), 0.9), np.quantile(np.abs(ar), 0.9))
    assert raw > limit  # one sample at a time this would read as saturation
    assert not saturated(_times(noisy), noisy, vp.lf, vp.lr, limit)
    # the same noise on a tyre past its peak: the rear slides at twice the limit
    slide = noisy.copy()
    slide[:, 6] -= 2 * limit
    assert saturated(_times(slide), slide, vp.lf, vp.lr, limit)
    # a slide in the window's newest 0.3 s is read (the mean is not padded at the end)
    late = noisy.copy()
    late[-30:, 6] -= 4 * limit
    assert saturated(_times(late), late, vp.lf, vp.lr, limit)


def _first_fit(est, mu: float, mu_lower_bound: float):
    """Context 0's first fit, not identifiable: ``mu`` (std 0.5) with the car's stiffness and
    the used-friction bound ``mu_lower_bound``; returns the context's slot."""
    slot = est._slots[0]
    slot.estimate = replace(
        slot.estimate,
        theta=(mu, est.params.C_Sf, est.params.C_Sr),
        theta_std=(0.5, np.nan, np.nan),
        fits=1,
        mu_lower_bound=mu_lower_bound,
    )
    return slot


def _fitted_estimator(**cfg):
    est = ContextEstimator(ford_escort(), probing(sample_period_s=0.02, **cfg))
    est.add_sample(0.0, np.array([0, 0, 0, 8.0, 0, 0, 0]), [0, 0], [0])
    return est, _first_fit(est, 1.5, 0.2)


def _feed(est, t0, t1, beta=0.0):
    for t in np.arange(t0, t1, 0.02):
        est.add_sample(float(t), np.array([0, 0, 0, 8.0, 0, 0, beta]), [0, 0], [0])


def test_estimator_probes_a_not_identifiable_context_and_backs_off():
    # straight running gives no bend evidence: with the bend ratio in use (the default) the
    # probe stays; the time-based 10 % steps are the rule without it
    est, _ = _fitted_estimator()
    est.update_probe(0.0)
    for k in range(3):
        _feed(est, 0.02 + 3.0 * k, 3.0 * (k + 1))
        est.update_probe(3.0 * (k + 1))
    assert est.theta_for()[0] == pytest.approx(0.3) and est.table().get(0).probe.steps == 0
    est, slot = _fitted_estimator()
    th0 = est.theta_for()
    assert th0[0] == pytest.approx(0.3)  # before the first update: the lower bound's value
    np.testing.assert_allclose(th0[0] * th0[1:], 1.5 * np.array(slot.estimate.theta[1:]))
    est.update_probe(0.0)
    _feed(est, 0.02, 24.0)
    est.update_probe(24.0)
    assert est.theta_for()[0] == pytest.approx(0.3)  # a straight: no evidence, no raise
    est.handing.contexts[0].probe = ProbeState(mu=0.28 / 0.64, last_step_s=21.0, steps=3)
    # the rear slides: back off at once
    _feed(est, 24.02, 24.6, beta=0.1)
    est.update_probe(24.6)
    assert est.theta_for()[0] == pytest.approx(0.28 / 0.64 / 1.21)
    assert est.table().get(0).handing == "backed_off"
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
    from pcvfe_drake.models.tyre_effects import MF_SHAPE as PEAK_TYRE_SHAPE

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
    assert saturated(_times(x), x, vp.lf, vp.lr, (0.05, 0.02))
    assert not saturated(_times(x), x, vp.lf, vp.lr, (0.05, 0.04))


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
    assert not saturated(_times(x), x, vp.lf, vp.lr, 0.002)
    x[:, 6] += 2 * MIN_SLIP_LIMIT_RAD
    assert saturated(_times(x), x, vp.lf, vp.lr, 0.002)


def _mf_slalom(peak, amplitude_rad, seconds=6.0, v=6.0, noise=False, seed=0, stiffness=1.0):
    """States (N, 7) at 100 Hz of a single-track car at constant speed on magic-formula tyres
    (shape 1.35, ``stiffness`` times the Ford Escort's stiffness per unit load at mu = 1, i.e.
    ``peak`` where the stiffness follows the friction, friction peak ``peak``), steered
    ``amplitude_rad sin(2 pi t / 6 s)`` (a bend every 3 s, as the paper's slalom at 6 m/s);
    ``noise``: INS-like noise on the side slip (0.005 rad) and yaw rate (0.01 rad/s)."""
    from pcvfe_drake.estimation.probe import MF_SHAPE

    vp = ford_escort()
    L = vp.lf + vp.lr
    fz = np.array([vp.lr, vp.lf]) / L * vp.m * 9.81
    k = stiffness * np.array([vp.C_Sf, vp.C_Sr])  # small-slip stiffness per unit load
    dt, beta, r, rows = 1e-3, 0.0, 0.0, []
    for i in range(int(seconds / dt)):
        t = i * dt
        delta = amplitude_rad * np.sin(2 * np.pi * t / 6.0)
        x = np.array([[0, 0, delta, v, 0, r, beta]])
        af, ar = (a[0] for a in axle_slip_angles(x, vp.lf, vp.lr))
        f = fz * peak * np.sin(MF_SHAPE * np.arctan(k * np.array([af, ar]) / (MF_SHAPE * peak)))
        if i % 10 == 0:
            rows.append([0, 0, delta, v, 0, r, beta])
        beta += dt * ((f[0] + f[1]) / (vp.m * v) - r)
        r += dt * (vp.lf * f[0] - vp.lr * f[1]) / vp.I_z
    x = np.array(rows)
    if noise:
        rng = np.random.default_rng(seed)
        x[:, 6] += rng.normal(0.0, 0.005, len(x))
        x[:, 5] += rng.normal(0.0, 0.01, len(x))
    return np.arange(len(x)) * 0.01, x, k


def test_bend_ratio_reads_how_far_along_the_tyre_curve_the_car_works():
    from pcvfe_drake.estimation.probe import bend_ratios

    vp = ford_escort()

    def ratios(peak, amp, **kw):
        t, x, k = _mf_slalom(peak, amp, **kw)
        return bend_ratios(t, x, vp.lf, vp.lr, vp.I_z / vp.m, k, 0.1)

    # the same steering (lateral force up to ~0.33 of the axle load) on a high and on a low
    # peak: linear on the high one, bent near the low one, in between on sand-like 0.45
    assert all(abs(b - 1.0) < 0.02 for b in ratios(2.0, 0.2))
    assert min(ratios(0.34, 0.2)) > 1.25  # q ~0.95: beyond the back-off limit
    assert 1.1 < max(ratios(0.45, 0.2)) < 1.25  # q ~0.73: the slow steps' band
    assert max(ratios(0.6, 0.15)) <= 1.1  # q ~0.41: fast steps
    # the INS-like noise scatters the ratio, it does not bias it
    for seed in range(3):
        assert all(abs(b - 1.0) < 0.05 for b in ratios(2.0, 0.2, noise=True, seed=seed))
        assert min(ratios(0.34, 0.2, noise=True, seed=seed)) > 1.25
    # straight running: no force, no evidence
    t, x, k = _mf_slalom(2.0, 0.0)
    assert all(np.isnan(b) for b in bend_ratios(t, x, vp.lf, vp.lr, vp.I_z / vp.m, k, 0.1))


def test_the_implied_peak_is_consistent_with_a_stiffness_that_follows_the_friction():
    """Where the car's stiffness follows the friction (``peak_and_stiffness``), a level below
    the peak reads the bends with a softer tyre than the car has: the ratio reads nearly
    linear and the peak read without the law (0) lies far above the truth. Read with the law
    (1), the implied peak is the truth (the slalom's own demand over the level as the share)."""
    from pcvfe_drake.estimation.probe import (
        axle_force_per_load,
        bend_ratios,
        implied_level_ratio,
        implied_peak_fraction,
    )

    vp = ford_escort()
    cases = ((0.67, 0.62, 0.2), (0.67, 0.62, 0.3), (0.9, 0.5, 0.2), (0.5, 0.6, 0.2))
    for peak, level, amp in cases:  # (true peak, level handed, steering amplitude [rad])
        t, x, k = _mf_slalom(peak, amp, stiffness=peak)
        _, f_f, f_r = axle_force_per_load(t, x, vp.lf, vp.lr, vp.I_z / vp.m)
        demand = float(np.quantile(np.maximum(np.abs(f_f), np.abs(f_r)), 0.99))
        share = demand / level
        stiffness_at_level = level * k / peak  # mu * C_S at the level handed
        bend = max(bend_ratios(t, x, vp.lf, vp.lr, vp.I_z / vp.m, stiffness_at_level, demand / 2))
        consistent = implied_level_ratio(bend, share, stiffness_law=1.0) * level
        assert consistent == pytest.approx(peak, abs=0.01)
        without = implied_level_ratio(bend, share, stiffness_law=0.0) * level
        assert without == pytest.approx(share / implied_peak_fraction(bend) * level)
        if level < peak:
            assert without > 1.2 * peak  # a fast step past the truth
        else:
            assert without < peak  # above the truth it reads too low (a back-off's side)
    assert math.isnan(implied_level_ratio(float("nan"), 0.64, 1.0))


def test_magic_formula_bend_ratios_behind_the_thresholds():
    from pcvfe_drake.estimation.probe import MF_SHAPE, sine_bend_ratio

    def ratio_at(q):  # slip needed over a linear tyre's, at q of the peak
        x = np.tan(np.arcsin(q) / MF_SHAPE)
        return MF_SHAPE * x / q

    assert ratio_at(0.5) == pytest.approx(1.1, abs=0.01)
    assert ratio_at(1.0) == pytest.approx(3.12, abs=0.01)
    # over a whole bend (force q sin of the peak): the probe's thresholds, derived from the
    # planner's share (0.64) of a handed mu equal to the peak, and one 25 % step above it
    settings = ProbeSettings(use_fraction=0.64)
    assert sine_bend_ratio(0.64) == settings.linear_ratio == pytest.approx(1.14, abs=0.005)
    assert settings.bend_limit == sine_bend_ratio(0.80) == pytest.approx(1.25, abs=0.01)


FAST = dict(fast_step_rel=0.25, linear_ratio=1.14, bend_limit=1.25)


def test_probe_step_size_follows_the_bend_ratio():
    s = ProbeState(mu=0.4, last_step_s=0.0)
    lb = 0.4  # demonstrated enough that the excess cap is far
    fast = probe_step(
        s,
        3.0,
        lower_bound=lb,
        floor_mu=0.3,
        prior_mu=1.05,
        is_saturated=False,
        bend=1.0,
        **RULES,
        **FAST,
    )
    assert fast.mu == pytest.approx(0.5) and fast.steps == 1
    slow = probe_step(
        s,
        3.0,
        lower_bound=lb,
        floor_mu=0.3,
        prior_mu=1.05,
        is_saturated=False,
        bend=1.2,
        **RULES,
        **FAST,
    )
    assert slow.mu == pytest.approx(0.4) and slow.steps == 0  # bent within the limit: stays
    assert slow is s  # and the level's evidence carries on from where the level was set
    from pcvfe_drake.estimation.probe import implied_peak_fraction, sine_bend_ratio

    for q in (0.3, 0.57, 0.64, 0.8):
        assert implied_peak_fraction(sine_bend_ratio(q)) == pytest.approx(q, abs=2e-3)
    near = probe_step(
        s,
        3.0,
        lower_bound=lb,
        floor_mu=0.3,
        prior_mu=1.05,
        is_saturated=False,
        bend=sine_bend_ratio(0.57),
        **RULES,
        **FAST,
    )
    # the demand (0.64 x 0.4) was 0.57 of the peak: raised to that peak, less than a fast step
    assert near.mu == pytest.approx(0.64 * 0.4 / 0.57, rel=5e-3) and near.steps == 1
    unknown = probe_step(
        s, 3.0, lower_bound=lb, floor_mu=0.3, prior_mu=1.05, is_saturated=False, **RULES, **FAST
    )
    assert unknown.mu == pytest.approx(0.4)  # no evidence (a straight): stays
    old = probe_step(
        s,
        3.0,
        lower_bound=lb,
        floor_mu=0.3,
        prior_mu=1.05,
        is_saturated=False,
        bend=1.2,
        **RULES,
        **{**FAST, "fast_step_rel": None},
    )
    assert old.mu == pytest.approx(0.44)  # the bend unused for the raise: the 10 % step
    bent = probe_step(
        s,
        1.0,
        lower_bound=0.2,
        floor_mu=0.3,
        prior_mu=1.05,
        is_saturated=False,
        bend=1.5,
        **RULES,
        **FAST,
    )
    assert bent.backoffs == 1 and bent.mu == pytest.approx(0.4 / 1.21)  # at once, no hold
    assert bent.ceiling == pytest.approx(0.4 / 1.1)
    # the fast step is still bounded by the demonstrated friction
    capped = probe_step(
        s,
        3.0,
        lower_bound=0.2,
        floor_mu=0.3,
        prior_mu=1.05,
        is_saturated=False,
        bend=1.0,
        **RULES,
        **FAST,
    )
    assert capped.mu == pytest.approx(0.28 / 0.64)


def test_probe_with_bend_ratio_rises_fast_stops_near_the_peak_and_backs_off():
    """A car that uses the planner's demand (0.64 of the handed mu) and whose tyres show the
    magic formula's bend ratio over a bend at that demand: on a high peak the probe climbs in
    fast steps and stops near the peak, on a low one it stops too; a tyre that stays linear up
    to 3/4 of its peak and then slides makes it back off."""
    from pcvfe_drake.estimation.probe import sine_bend_ratio

    def mf(q):
        return np.inf if q >= 1.0 else sine_bend_ratio(q)

    def drive(peak, seconds=40, tyre=mf):
        s, lb, history = ProbeState(), 0.2, []
        for t in np.arange(0.0, seconds, 1.0):
            demand = 0.64 * (s.mu if s.started else 0.3)
            lb = max(lb, min(demand, peak))
            s = probe_step(
                s,
                float(t),
                lower_bound=lb,
                floor_mu=0.3,
                prior_mu=1.05,
                is_saturated=False,
                bend=tyre(demand / peak),
                **RULES,
                **FAST,
            )
            history.append(s.mu)
        return s, np.array(history)

    s, mu = drive(0.8)
    # 0.3 -> between the peak and 1.25 times it (the back-off limit) in 5 fast steps (15 s),
    # then it stays there: no back-off
    assert 0.8 <= mu[15] <= 1.25 * 0.8 and s.steps == 5 and s.backoffs == 0
    assert np.all(mu[15:] == mu[15])
    slow = ProbeState()
    for t in np.arange(0.0, 16.0, 1.0):  # the 10 % steps alone are still below 0.5 there
        slow = probe_step(
            slow,
            float(t),
            lower_bound=0.64 * (slow.mu if slow.started else 0.3),
            floor_mu=0.3,
            prior_mu=1.05,
            is_saturated=False,
            **RULES,
        )
    assert slow.mu < 0.5
    s, mu = drive(0.35)
    assert s.backoffs == 0 and 0.35 <= mu[-1] <= 1.25 * 0.35
    s, mu = drive(0.35, tyre=lambda q: 1.0 if q < 0.75 else 2.0)
    assert s.backoffs >= 1 and mu.max() <= 1.25 * 1.1 * 0.35
    assert 0.3 <= mu[-1] and 0.64 * mu[-1] < 0.75 * 0.35  # settled where it does not slide


def test_estimator_reads_the_bend_ratio_of_the_current_level():
    """The estimator's probe: fast steps while the slalom's data are linear, a back-off as soon
    as the current level's data bend past the limit (no large slip angles involved)."""
    params = ford_escort()
    est = ContextEstimator(params, probing(sample_period_s=0.01))
    est.add_sample(0.0, np.array([0, 0, 0, 6.0, 0, 0, 0]), [0, 0], [0])
    _first_fit(est, 1.0, 0.3)  # handed stiffness mu * C_S = C_S: _mf_slalom's

    def drive(t0, peak, seconds=3.0):
        t, x, _ = _mf_slalom(peak, 0.2, seconds=seconds)
        for ti, xi in zip(t, x, strict=True):
            est.add_sample(t0 + 0.01 + float(ti), xi, [0, 0], [0])
        est.update_probe(t0 + seconds)
        return est.theta_for()[0]

    est.update_probe(0.0)  # starts at max(bound, floor)
    mus = [drive(3.0 * k, 2.0) for k in range(4)]
    # linear data: 25 % steps up to the demonstrated-friction cap (0.3 + 0.08) / 0.64
    np.testing.assert_allclose(mus, [0.3 * 1.25, 0.3 * 1.25**2, 0.3 * 1.25**3, 0.38 / 0.64])
    # the next level's data bend (peak 0.34 under a ~0.33 demand): back off, no hold needed
    mu = drive(12.0, 0.34, seconds=2.0)
    assert mu == pytest.approx(0.38 / 0.64 / 1.21)
    from pcvfe_drake.estimation.probe import peak_slip_rad

    t, x, k = _mf_slalom(0.34, 0.2, seconds=2.0)  # the slip-angle test alone would not have
    assert not saturated(t, x, params.lf, params.lr, 0.5 * peak_slip_rad(0.38 / 0.64, k))
    assert est.table().get(0).probe.backoffs == 1


def test_an_identified_estimate_is_handed_also_below_the_floor():
    est, slot = _fitted_estimator()
    slot.estimate = replace(
        slot.estimate, theta=(0.55, *slot.estimate.theta[1:]), identifiable=True
    )
    assert est.theta_for()[0] == 0.55
    # (an identifiable peak is never below the friction its data used)
    low = replace(slot.estimate, theta=(0.17, *slot.estimate.theta[1:]), mu_lower_bound=0.15)
    slot.estimate = low
    th = est.theta_for()
    assert th[0] == pytest.approx(0.17)  # the floor is a guess, the fit a measurement
    np.testing.assert_array_equal(th, low.theta)
    assert est.table().get(0).handing == "identified"


def test_probe_cap_of_a_not_identifiable_estimate_is_never_below_the_floor():
    est, slot = _fitted_estimator()
    std = (0.01, *slot.estimate.theta_std[1:])
    low = replace(
        slot.estimate, theta=(0.18, *slot.estimate.theta[1:]), identifiable=False, theta_std=std
    )
    slot.estimate = low
    th = est.theta_for()
    assert th[0] == pytest.approx(0.3)  # not the cap 0.18 + 1.96 * 0.01
    np.testing.assert_allclose(th[0] * th[1:], 0.18 * np.array(low.theta[1:]))  # stiffness kept
    # a cap above the floor still limits the probe's level
    est.handing.contexts[0] = ContextHanding(ProbeState(mu=0.5, last_step_s=0.0, steps=2))
    slot.estimate = replace(low, theta=(0.32, *low.theta[1:]))
    assert est.theta_for()[0] == pytest.approx(0.32 + 1.96 * 0.01)


def test_a_level_not_tried_in_a_bend_gives_no_evidence():
    from pcvfe_drake.estimation.probe import bend_ratios, level_bend

    vp = ford_escort()
    t, x, k = _mf_slalom(2.0, 0.2)  # axle forces up to ~0.33 of the load
    full = level_bend(t, x, vp, k, 0.1, demand=0.35)
    assert full == pytest.approx(max(bend_ratios(t, x, vp.lf, vp.lr, vp.I_z / vp.m, k, 0.1)))
    # the same data for a level whose planner demand (0.64 x 0.8) the bend never approached
    assert np.isnan(level_bend(t, x, vp, k, 0.1, demand=0.64 * 0.8))
    # a gentler bend (forces up to ~0.17): evidence enough for a ratio, not for a 0.35 demand
    t, x, k = _mf_slalom(2.0, 0.1)
    assert max(bend_ratios(t, x, vp.lf, vp.lr, vp.I_z / vp.m, k, 0.1)) < 1.14  # reads linear
    assert np.isnan(level_bend(t, x, vp, k, 0.1, demand=0.35))
    assert np.isfinite(level_bend(t, x, vp, k, 0.1, demand=0.2))


def test_probe_takes_its_first_step_at_the_id_on_the_data_driven_at_the_floor():
    """``start_bend``: the bends the car drove at the stated floor before the context had its
    id are a level tried; where they read linear the probe starts one step up at once, where
    they bend (or are missing, or slide) it starts at its base and holds it."""
    from pcvfe_drake.estimation.probe import sine_bend_ratio

    rules = {**RULES, "max_excess": 0.12, **FAST, "fast_step_rel": 0.4}

    def start(bend, lb=0.2, sat=False, floor_mu=0.3, start_mu=0.3, **kw):
        kw = {**rules, **kw}
        return probe_step(
            ProbeState(),
            10.0,
            lower_bound=lb,
            floor_mu=floor_mu,
            prior_mu=1.05,
            is_saturated=sat,
            start_bend=bend,
            start_mu=start_mu,
            **kw,
        )

    s = start(1.0)  # linear: the implied peak is far; one fast step above the floor
    assert s.mu == pytest.approx(0.42) and s.steps == 1 and s.last_step_s == 10.0
    held = probe_step(
        s,
        12.9,
        lower_bound=0.2,
        floor_mu=0.3,
        prior_mu=1.05,
        is_saturated=False,
        bend=1.0,
        **rules,
    )
    assert held is s  # the next raise waits hold_s on the new level's own data
    # the floor's demand (0.64 x 0.3) was 0.57 of the peak: to that peak
    assert start(sine_bend_ratio(0.57)).mu == pytest.approx(0.64 * 0.3 / 0.57, rel=5e-3)
    # bounded by the demonstrated friction: (0.15 + 0.08) / 0.64
    assert start(1.0, lb=0.15, max_excess=0.08).mu == pytest.approx(0.23 / 0.64)
    for bend, sat in ((1.2, False), (float("nan"), False), (1.0, True)):
        s = start(bend, sat=sat)  # bent, no evidence, sliding: the base
        assert s.mu == pytest.approx(0.3) and s.steps == 0
    assert start(1.0, fast_step_rel=None).mu == pytest.approx(0.3)  # the bend not in use
    # a floor near the peak on a car whose stiffness follows the friction: bends at 0.64 of a
    # floor 0.62 on a peak 0.67, read with the floor's stiffness, look linear (the ratio of
    # q = 0.59 times 0.62 / 0.67); without the law that is a full fast step (40 % above the
    # floor, 30 % above the peak), with it the step stops at the peak
    bend = sine_bend_ratio(0.64 * 0.62 / 0.67) * 0.62 / 0.67
    floor_near = {"lb": 0.45, "floor_mu": 0.62, "start_mu": 0.62}
    assert start(bend, **floor_near).mu == pytest.approx(0.62 * 1.4)
    assert start(bend, **floor_near, stiffness_law=1.0).mu == pytest.approx(0.67, abs=0.003)
    # once started the start evidence is not read again
    later = probe_step(
        ProbeState(mu=0.3, last_step_s=0.0),
        1.0,
        lower_bound=0.2,
        floor_mu=0.3,
        prior_mu=1.05,
        is_saturated=False,
        start_bend=1.0,
        start_mu=0.3,
        **rules,
    )
    assert later.mu == pytest.approx(0.3) and later.steps == 0


def test_a_probe_starting_at_the_level_already_driven_counts_it_from_then():
    """A probe whose start level is the one the context's data were driven at (the stated floor)
    holds it from the context's first sample, not from its own start, so the bends driven
    there are its level's evidence; a start above that level is a new level, held from now."""
    rules = {**RULES, "max_excess": 0.12, **FAST, "fast_step_rel": 0.4}

    def start(lb, since_s):
        return probe_step(
            ProbeState(),
            10.0,
            lower_bound=lb,
            floor_mu=0.3,
            prior_mu=1.05,
            is_saturated=False,
            start_bend=float("nan"),  # no bend yet when it starts
            start_mu=0.3,
            start_since_s=since_s,
            **rules,
        )

    def then(state, t_now):  # the level's data now hold a linear bend
        return probe_step(
            state,
            t_now,
            lower_bound=0.2,
            floor_mu=0.3,
            prior_mu=1.05,
            is_saturated=False,
            bend=1.0,
            **rules,
        )

    driven = start(0.2, 6.0)
    assert driven.mu == pytest.approx(0.3) and driven.last_step_s == 6.0
    assert then(driven, 11.0).mu == pytest.approx(0.42)  # 5 s at the floor: a step at once
    fresh = start(0.2, float("nan"))
    assert fresh.last_step_s == 10.0 and then(fresh, 11.0) is fresh  # held from now
    above = start(0.35, 6.0)  # the data used more than the floor: the start is a new level
    assert above.mu == pytest.approx(0.35) and above.last_step_s == 10.0


def test_estimator_starts_the_probe_on_the_bends_driven_before_the_id():
    params = ford_escort()

    def first_level(peak, **cfg):
        est = ContextEstimator(params, probing(sample_period_s=0.01, **cfg))
        t, x, _ = _mf_slalom(peak, 0.2, seconds=6.0)  # two bends before the first fit
        for ti, xi in zip(t, x, strict=True):
            est.add_sample(float(ti), xi, [0, 0], [0])
        _first_fit(est, 1.0, 0.3)
        est.update_probe(6.0)
        return est.theta_for()[0], est.table().get(0).probe.steps

    stated = dict(floor_stated=True)
    assert first_level(2.0) == (pytest.approx(0.3), 0)  # without it: the base, held
    assert first_level(2.0, **stated) == (pytest.approx(0.3 * 1.25), 1)  # linear: one step
    assert first_level(0.25, **stated) == (pytest.approx(0.3), 0)  # bent: the base


def test_unknown_phase_probe_takes_one_step_above_the_floor_and_backs_off():
    """``probe_unknown``: while the terrain is unknown the bends since the phase began are a
    level tried at the floor; linear ones raise it once (never twice: the terrain under a noise
    frame may change), bent ones keep it, a slide takes it back to the floor."""
    from pcvfe_drake.estimation.probe import unknown_probe_update

    vp = ford_escort()
    cfg = ProbeSettings(floor_mu=0.3, fast_step_rel=0.4, max_excess=0.12, start_evidence=True)

    def run(peak, seconds=9.0, beta=0.0):
        t, x, k = _mf_slalom(peak, 0.2, seconds=seconds)
        x[:, 6] += beta
        s, history = ProbeState(), []
        for now in np.arange(0.0, seconds + 0.01, 1.0):

            def since(t0, now=now):
                keep = (t >= t0) & (t <= now)
                return t[keep], x[keep]

            s = unknown_probe_update(s, float(now), cfg, vp, 0.3, k, since, 1.05)
            history.append(s.mu)
        return s, history

    s, mus = run(2.0)  # linear: one step (0.3 x 1.4) after the 3 s hold, then no more
    assert mus[0] == pytest.approx(0.3) and s.steps == 1
    assert max(mus) == pytest.approx(0.42) and mus[-1] == pytest.approx(0.42)
    s, mus = run(0.45)  # bent (ratio 1.20 at this steering), not past the limit: kept
    assert s.steps == 0 and s.backoffs == 0 and max(mus) == pytest.approx(0.3)
    s, mus = run(0.22)  # a peak below the floor: saturated, never above the floor
    assert s.backoffs >= 1 and max(mus) == pytest.approx(0.3)
    raised = ProbeState(mu=0.42, last_step_s=0.0, steps=1)
    t, x, k = _mf_slalom(2.0, 0.2, seconds=3.0)
    x[:, 6] -= 0.1  # the rear slides
    back = unknown_probe_update(
        raised, 3.0, cfg, vp, 0.3, k, lambda t0: (t[t >= t0], x[t >= t0]), 1.05
    )
    assert back.mu == pytest.approx(0.3) and back.backoffs == 1


def test_the_unknown_phase_level_is_carried_into_the_context_it_was_tried_on():
    from pcvfe_drake.estimation.probe import carried_probe

    level = ProbeState(mu=0.42, last_step_s=4.0, steps=1)
    assert carried_probe(level, np.array([3] * 9 + [-1]), 3) == level
    assert carried_probe(level, np.array([3] * 5 + [-1] * 5), 3) is None  # another terrain
    assert carried_probe(ProbeState(mu=0.3, last_step_s=0.0), np.array([3]), 3) is None
    backed = ProbeState(mu=0.3, ceiling=0.3, last_step_s=4.0, steps=1, backoffs=1)
    assert carried_probe(backed, np.array([3] * 10), 3) is None  # backed off: not carried
    # the estimator: the phase's step on noise frames; the terrain's samples join the context
    # when it is named (eq. 5d) and the context starts from the phase's level
    params = ford_escort()
    est = ContextEstimator(params, probing(floor_stated=True, sample_period_s=0.01))
    t, x, _ = _mf_slalom(2.0, 0.2, seconds=8.0)
    for now in range(9):
        for ti, xi in zip(t, x, strict=True):
            if now - 1 < ti <= now:
                est.add_sample(float(ti), xi, [0, 0], [0 if ti > 5.0 else -1])
        if now == 5:  # the re-clustering names the terrain: its noise samples join context 0
            frames = np.arange(0.0, 5.0, 0.1)
            est.relabel(frames, np.zeros(frames.size, int), 0.1, version=1)
        est.update_probe(float(now))
        if now == 5:  # one step while unknown (default fast step), not carried yet
            assert est.theta_for()[0] == pytest.approx(0.3 * 1.25)
            step_s = est.handing.unknown_probe.last_step_s
    # named: the phase ends, the context starts at the phase's level, whose data since the
    # phase's step (3 s, linear) give the next step at once; no fit needed
    assert not est.handing.unknown_probe.started and _probe(est).steps == 2
    assert _probe(est).last_step_s == 6.0 and step_s == 3.0
    assert est.theta_for()[0] == pytest.approx(0.3 * 1.25**2)


def _explore_unfitted(peak, seconds=7.0, **cfg):
    """Context 0 driven on a slalom (friction peak ``peak``) from its first sample, with a
    probe update every second and no fit; returns the estimator."""
    est = ContextEstimator(ford_escort(), probing(sample_period_s=0.01, **cfg))
    t, x, _ = _mf_slalom(peak, 0.2, seconds=seconds)
    for now in range(int(seconds) + 1):
        for ti, xi in zip(t, x, strict=True):
            if now - 1 < ti <= now:
                est.add_sample(float(ti), xi, [0, 0], [0])
        est.update_probe(float(now))
    return est


def test_a_confirmed_context_is_explored_before_its_first_fit():
    """With a stated floor the data a context has before its first fit were driven at the floor,
    and the probe's evidence reads the tyres, not the fit: a confirmed context climbs from its
    first samples, by the same rules (a linear bend: a step per hold; a slide: a back-off, never
    below the floor). Without a stated floor, or before the visit is confirmed, it gets the
    unknown value until its fit."""
    est = _explore_unfitted(2.0, floor_stated=True)
    assert not est.fits()[0].fitted and est.handing_state(0) == "exploring"
    assert _probe(est).steps == 2 and est.theta_for()[0] == pytest.approx(0.3 * 1.25**2)
    assert est.theta_for(0)[0] == pytest.approx(0.3 * 1.25**2)
    assert est.table().get(0).probe.steps == 2
    prior = est.prior_theta  # the prior's small-slip stiffness mu * C_S is kept
    theta = est.theta_for()
    np.testing.assert_allclose(theta[0] * theta[1:], prior[0] * prior[1:])
    # a peak below the floor: the slips back it off at once, never above the floor
    low = _explore_unfitted(0.22, floor_stated=True)
    assert _probe(low).backoffs >= 1 and _probe(low).steps == 0
    assert low.theta_for()[0] == pytest.approx(0.3)
    # without a stated floor: the unknown value until the first fit
    conservative = _explore_unfitted(2.0)
    assert 0 not in conservative.handing.contexts and conservative.handing_state(0) == "unknown"
    assert conservative.theta_for()[0] <= 0.3
    # a visit not confirmed (the rise confirmation never passes): not explored
    est = ContextEstimator(ford_escort(), probing(floor_stated=True, sample_period_s=0.01))
    est.handing.visit.confirm_s = 100.0
    t, x, _ = _mf_slalom(2.0, 0.2, seconds=7.0)
    for now in range(8):
        for ti, xi in zip(t, x, strict=True):
            if now - 1 < ti <= now:
                est.add_sample(float(ti), xi, [0, 0], [0])
        est.update_probe(float(now))
    assert 0 not in est.handing.contexts and est.theta_for()[0] <= 0.3 * 1.25


def test_the_first_fit_takes_over_the_level_explored_before_it():
    """The first fit continues the probe where it is, capped by the fit's 95 % interval."""
    est = _explore_unfitted(2.0, floor_stated=True)
    level = 0.3 * 1.25**2
    _first_fit(est, 1.0, 0.3)  # wide: the level as it is
    assert est.theta_for()[0] == pytest.approx(level) and _probe(est).steps == 2
    slot = _first_fit(est, 0.4, 0.3)
    slot.estimate = replace(slot.estimate, theta_std=(0.02, np.nan, np.nan))
    assert est.theta_for()[0] == pytest.approx(0.4 + 1.96 * 0.02)  # a tight fit caps it


def test_a_renamed_context_keeps_the_level_explored_before_its_fit():
    est = _explore_unfitted(2.0, floor_stated=True)
    explored = _probe(est)
    frames = np.arange(0.0, 7.01, 0.1)
    est.relabel(frames, np.ones(frames.size, int), 0.1, version=1)  # all of context 0 -> 1
    assert _probe(est, 1) == explored


def test_a_back_off_after_an_identifiable_fit_is_judged_at_the_fit_level():
    """Slips driven while an identifiable fit was handed belong to the fit's level, not to the
    probe's: read at the probe's lower level they set its ceiling near the floor (0.33 for 18 s
    on concrete after fits of 0.67-0.78 for 0.60)."""
    from pcvfe_drake.estimation.probe import peak_slip_rad

    def run(beta_per_limit):
        est, slot = _fitted_estimator()
        slot.estimate = replace(slot.estimate, theta=(0.6, *slot.estimate.theta[1:]), fits=2)
        est.handing.contexts[0] = ContextHanding(ProbeState(mu=0.42, last_step_s=0.0, steps=1))
        theta = np.array(slot.estimate.theta)
        k = theta[0] * theta[1:]
        low = 0.5 * peak_slip_rad(0.42, k)[1]  # the rear's slip limits at the two levels
        high = 0.5 * peak_slip_rad(0.78, k)[1]
        assert high > 1.5 * low > 0.015
        slot.estimate = replace(slot.estimate, theta=(0.78, *theta[1:]), identifiable=True)
        est.update_probe(3.0)
        assert est.theta_for()[0] == pytest.approx(0.78)
        _feed(est, 3.02, 4.0, beta=beta_per_limit(low, high))
        slot.estimate = replace(slot.estimate, theta=(0.6, *theta[1:]), identifiable=False)
        est.update_probe(4.0)
        return est, est.table().get(0).probe

    # large for the probe's 0.42, not for the 0.78 handed: no back-off
    est, p = run(lambda low, high: 1.3 * low)
    assert p.mu == pytest.approx(0.42) and p.backoffs == 0 and p.ceiling == float("inf")
    # the car's speed answers the fit's level for probe_hold_s after it; then the probe's own
    _feed(est, 4.02, 6.9, beta=1.3 * 0.5 * peak_slip_rad(0.42, 0.6 * est.params.C_Sr))
    est.update_probe(6.9)
    assert est.table().get(0).probe.backoffs == 0
    _feed(est, 6.92, 7.1, beta=1.3 * 0.5 * peak_slip_rad(0.42, 0.6 * est.params.C_Sr))
    est.update_probe(7.1)
    p = est.table().get(0).probe
    assert p.backoffs == 1 and p.ceiling == pytest.approx(max(0.42 / 1.1, 0.3))
    # large for the 0.78 handed too: the ceiling is one step below the level that saturated
    _, p = run(lambda low, high: 1.3 * high)
    assert p.backoffs == 1 and p.ceiling == pytest.approx(0.78 / 1.1)
    assert p.mu == pytest.approx(0.42)  # already below two steps down from 0.78


def test_a_level_tried_in_a_bend_rises_to_a_tight_fit_not_yet_identifiable():
    """``fit_mu`` (``probe_fit_target``): where the level's bend ratio is bent but within the
    limit (the ratio's noise at a third of the peak: concrete's floor read 1.11-1.15 on the
    multi-body truth), a tight fit above the level is raised to, a fast step at a time, within
    the bounds; no evidence (a straight) or a saturated level still holds or backs off."""
    from pcvfe_drake.estimation.probe import sine_bend_ratio

    rules = {**RULES, "max_excess": 0.12, **FAST, "fast_step_rel": 0.4}

    def step(state, bend, fit_mu=float("nan"), lb=0.26, t=3.0, **kw):
        return probe_step(
            state,
            t,
            lower_bound=lb,
            floor_mu=0.3,
            prior_mu=1.05,
            is_saturated=False,
            bend=bend,
            fit_mu=fit_mu,
            **{**rules, **kw},
        )

    s = ProbeState(mu=0.3, last_step_s=0.0)
    assert step(s, 1.15) is s  # without a fit: bent within the limit, held
    up = step(s, 1.15, fit_mu=0.62)
    assert up.mu == pytest.approx(0.42) and up.steps == 1  # one fast step toward the fit
    assert step(up, 1.15, fit_mu=0.62, t=6.0).mu == pytest.approx(0.42 * 1.4)
    up2 = step(up, 1.15, fit_mu=0.62, lb=0.22, t=6.0)
    assert up2.mu == pytest.approx(0.34 / 0.64)  # the demonstrated-friction cap (0.22 + 0.12)
    assert step(up, 1.15, fit_mu=0.5, lb=0.4, t=6.0).mu == pytest.approx(0.5)  # to the fit
    assert step(s, 1.15, fit_mu=0.62, t=2.9) is s  # the hold still applies
    assert step(s, float("nan"), fit_mu=0.62) is s  # not tried in a bend: no evidence
    assert step(s, 1.15, fit_mu=0.28) is s  # a fit below the level is no target
    # a linear level's implied peak above the fit still wins
    assert step(s, 1.0, fit_mu=0.33).mu == pytest.approx(0.42)
    bent = step(s, 1.3, fit_mu=0.62)
    assert bent.backoffs == 1 and bent.mu == pytest.approx(0.3)  # saturated: backs off
    # the first step at the id, on the bends driven at the floor before it
    start = dict(start_mu=0.3, t=10.0)
    assert step(ProbeState(), float("nan"), start_bend=1.142, **start).mu == pytest.approx(0.3)
    first = step(ProbeState(), float("nan"), start_bend=1.142, fit_mu=0.62, **start)
    assert first.mu == pytest.approx(0.42) and first.steps == 1
    for start_bend in (1.3, float("nan")):
        held = step(ProbeState(), float("nan"), start_bend=start_bend, fit_mu=0.62, **start)
        assert held.mu == pytest.approx(0.3) and held.steps == 0
    assert sine_bend_ratio(0.32) < 1.05  # what a third of the peak reads without noise


def test_estimator_hands_the_probe_a_tight_fit_as_its_target(monkeypatch):
    import pcvfe_drake.handing.handing as updates

    seen = []
    original = updates.probe_update

    def spy(*args, **kwargs):
        seen.append(kwargs["fit_mu"])
        return original(*args, **kwargs)

    monkeypatch.setattr(updates, "probe_update", spy)
    for std, below, expected in (
        (0.01, False, 0.62),
        (0.2, False, None),  # a loose fit is no target
        (0.01, True, None),  # a fit below the used friction neither
    ):
        est, slot = _fitted_estimator()
        slot.estimate = replace(slot.estimate, theta=(0.62, *slot.estimate.theta[1:]))
        slot.estimate = replace(slot.estimate, theta_std=(std, np.nan, np.nan), below_used=below)
        _feed(est, 0.02, 1.0)
        est.update_probe(1.0)
        got = seen.pop()
        assert got == pytest.approx(expected) if expected else np.isnan(got)


def test_the_stiffness_law_reads_only_a_level_handed_with_the_models_stiffness(monkeypatch):
    """A level handed before a context's fit (and the unknown value) has the stiffness the
    car's model states for it, so its bends are read by the model's law; a fitted context's
    level keeps the fit's own stiffness, which the data set: no law between them."""
    import pcvfe_drake.handing.handing as updates

    laws = {"fitted": [], "unfitted": [], "unknown": []}
    original, original_unknown = updates.probe_update, updates.unknown_probe_update

    def spy(*args, **kwargs):
        fitted = "fit_mu" in kwargs  # only a fitted context's update has a fit to rise to
        laws["fitted" if fitted else "unfitted"].append(kwargs.get("stiffness_law", 0.0))
        return original(*args, **kwargs)

    def spy_unknown(*args, **kwargs):
        laws["unknown"].append(kwargs.get("stiffness_law", 0.0))
        return original_unknown(*args, **kwargs)

    monkeypatch.setattr(updates, "probe_update", spy)
    monkeypatch.setattr(updates, "unknown_probe_update", spy_unknown)
    est = ContextEstimator(ford_escort(), probing(floor_stated=True, sample_period_s=0.01))
    est.handing.stiffness_law = 1.0  # as a peak_and_stiffness model states
    t, x, _ = _mf_slalom(2.0, 0.2, seconds=8.0)
    for now in range(9):
        for ti, xi in zip(t, x, strict=True):
            if now - 1 < ti <= now:
                est.add_sample(float(ti), xi, [0, 0], [0 if ti > 3.0 else -1])
        est.update_probe(float(now))
    assert laws["unfitted"] and set(laws["unfitted"]) == {1.0}
    assert laws["unknown"] and set(laws["unknown"]) == {1.0}
    est, _ = _fitted_estimator()
    est.handing.stiffness_law = 1.0
    _feed(est, 0.02, 1.0)
    est.update_probe(1.0)
    assert laws["fitted"] == [0.0]
