"""A switch to a context with more friction waits for confirmation (fitter.rise_confirm_s)."""

from dataclasses import replace

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator, LiveFitConfig
from pcvfe_drake.estimation.context_switch import RiseGuard
from pcvfe_drake.vehicle.params import ford_escort

STATE = np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
FRAME_S = 0.1


def test_guard_confirms_after_the_time_and_noise_does_not_reset_it():
    guard = RiseGuard(confirm_s=1.0)
    guard.observe(0.0, 2, 2)  # the first context: compared with the unknown-context value
    assert guard.pending(2) and guard.confirmed == -1
    guard.observe(0.9, 2, 2)
    assert guard.pending(2)
    guard.observe(1.0, 2, 2)
    assert not guard.pending(2) and guard.confirmed == 2
    guard.observe(1.1, 1, 1)  # a switch to context 1
    assert guard.pending(1) and guard.confirmed == 2
    guard.observe(1.5, -1, 1)  # noise in between (held on 1)
    assert guard.pending(1)
    guard.observe(2.1, 1, 1)  # 1 s after 1's first frame: confirmed
    assert not guard.pending(1) and guard.confirmed == 1
    # another context's id restarts the count; back on the confirmed one: nothing pending
    guard.observe(2.2, 3, 3)
    assert guard.pending(3)
    guard.observe(2.7, 4, 4)
    guard.observe(3.6, 4, 4)
    assert guard.pending(4) and guard.confirmed == 1
    guard.observe(3.7, 4, 4)
    assert guard.confirmed == 4
    guard.observe(3.8, 1, 1)
    assert guard.pending(1)
    # the unknown-context policy in use (long noise) is what a later switch is compared with
    guard.observe(9.0, -1, -1)
    assert guard.confirmed == -1
    # off: never pending
    assert not RiseGuard().pending(5)
    with pytest.raises(ValueError, match="confirm_s"):
        RiseGuard(confirm_s=-1.0)
    with pytest.raises(ValueError, match="rise_confirm_s"):
        LiveFitConfig(rise_confirm_s=float("nan"))


def _estimator(confirm_s: float) -> tuple[ContextEstimator, float]:
    """Grass (id 2, mu 0.3) driven for 5 s; concrete (id 1, mu 0.6) fitted earlier."""
    params = ford_escort()
    cfg = LiveFitConfig(noise_hold_s=1.0, rise_confirm_s=confirm_s, unknown_floor_mu=0.3)
    est = ContextEstimator(params, cfg)
    for ident, mu in ((1, 0.6), (2, 0.3)):
        est.add_sample(0.0, STATE, [0.0, 0.0], [ident])
        slot = est._slots[ident]
        slot.estimate = replace(
            slot.estimate, theta=(mu, params.C_Sf, params.C_Sr), theta_std=(0.01, 0, 0), fits=1
        )
    t = 0.0
    for _ in range(50):
        t += FRAME_S
        est.add_sample(t, STATE, [0.0, 0.0], [2])
    assert est.theta_for()[0] == 0.3
    return est, t


def _drive(est: ContextEstimator, t: float, ids: list[int]) -> tuple[list[float], float]:
    mus = []
    for ident in ids:
        t += FRAME_S
        est.add_sample(t, STATE, [0.0, 0.0], [ident])
        mus.append(float(est.theta_for()[0]))
    return mus, t


def test_a_stray_id_of_more_friction_is_not_handed_to_the_controller():
    # 0.4 s of a transition strip taken for concrete, then a terrain never seen (noise).
    strip = [1, 1, 1, 1] + [-1] * 25
    base, t = _estimator(0.0)
    mus, _ = _drive(base, t, strip)
    assert max(mus) == 0.6  # without the guard: concrete's mu, for the strip and the hold
    assert sum(m == 0.6 for m in mus) >= 10
    guarded, t = _estimator(1.0)
    mus, _ = _drive(guarded, t, strip)
    assert max(mus) == 0.3  # with it: grass' mu until the unknown-context value takes over
    assert mus[-1] == pytest.approx(0.28)  # the conservative value: grass' 0.3 - 2 std


def test_a_real_switch_to_more_friction_waits_confirm_s_and_to_less_none():
    est, t = _estimator(1.0)
    mus, t = _drive(est, t, [1] * 15)
    assert mus[:10] == [0.3] * 10  # the first 1.0 s on concrete: still grass' friction
    assert mus[10:] == [0.6] * 5  # then concrete's
    mus, t = _drive(est, t, [2] * 3)  # back to grass: less friction, at once
    assert mus == [0.3] * 3
    # and the theta handed while pending is the confirmed context's whole theta
    est2, t2 = _estimator(1.0)
    _drive(est2, t2, [1])
    np.testing.assert_array_equal(est2.theta_for(), est2.theta_for(2))
