"""The unknown-context policy: what PC-VFE hands the NMPC while the terrain is unknown."""

from dataclasses import replace

import numpy as np
import pytest

from pcvfe_drake.estimation.context_estimator import ContextEstimator, LiveFitConfig
from pcvfe_drake.estimation.unknown_context import unknown_context_theta
from pcvfe_drake.vehicle.params import ford_escort

PRIOR = np.array([1.05, 20.0, 20.0])


def test_policies_on_known_numbers():
    fitted = [(0.6, 0.01), (0.45, 0.05), (0.8, float("nan"))]
    last = np.array([0.6, 20.0, 20.0])
    np.testing.assert_array_equal(unknown_context_theta("prior", PRIOR, fitted, last), PRIOR)
    np.testing.assert_array_equal(unknown_context_theta("last_known", PRIOR, fitted, last), last)
    np.testing.assert_array_equal(unknown_context_theta("last_known", PRIOR, fitted, None), PRIOR)
    # conservative: min(floor 0.5, 0.6 - 0.02, 0.45 - 0.1, 0.8) = 0.35; the stiffnesses scaled so
    # that mu * C_S (the single-track tyre's small-slip stiffness) stays the prior's 1.05 * 20
    th = unknown_context_theta("conservative", PRIOR, fitted, last, floor_mu=0.5, sigmas=2.0)
    np.testing.assert_allclose(th, [0.35, 60.0, 60.0])
    np.testing.assert_allclose(th[0] * th[1:], PRIOR[0] * PRIOR[1:])
    # nothing fitted yet: the floor
    assert unknown_context_theta("conservative", PRIOR, [], None, floor_mu=0.3)[0] == 0.3
    with pytest.raises(ValueError, match="unknown_context"):
        unknown_context_theta("optimistic", PRIOR, [], None)


def _estimator(policy: str) -> ContextEstimator:
    params = ford_escort()
    est = ContextEstimator(params, LiveFitConfig(noise_hold_s=0.5, unknown_context=policy))
    state = np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    est.add_sample(0.0, state, [0.0, 0.0], [3])
    slot = est._slots[3]
    slot.estimate = replace(
        slot.estimate, theta=(0.8, params.C_Sf, params.C_Sr), theta_std=(0.01, 0, 0), fits=1
    )
    est.add_sample(0.1, state, [0.0, 0.0], [3])
    est.add_sample(0.2, state, [0.0, 0.0], [5])  # a new context, not fitted yet
    return est


@pytest.mark.parametrize(
    ("policy", "mu"), [("prior", 1.0489), ("last_known", 0.8), ("conservative", 0.3)]
)
def test_estimator_applies_the_policy_to_a_new_context_and_to_long_noise(policy, mu):
    est = _estimator(policy)
    assert est.theta_for()[0] == pytest.approx(mu, abs=1e-4)  # new context 5, no fit
    est.add_sample(0.3, np.array([0, 0, 0, 5.0, 0, 0, 0]), [0, 0], [-1])
    est.add_sample(1.5, np.array([0, 0, 0, 5.0, 0, 0, 0]), [0, 0], [-1])  # noise for 1.2 s
    assert est.theta_for()[0] == pytest.approx(mu, abs=1e-4)
    assert est.theta_for(3)[0] == 0.8  # an explicit id: its own estimate


def test_conservative_is_the_default_and_invalid_settings_are_named():
    assert LiveFitConfig().unknown_context == "conservative"
    with pytest.raises(ValueError, match="unknown_context"):
        LiveFitConfig(unknown_context="hope")
    with pytest.raises(ValueError, match="unknown_floor_mu"):
        LiveFitConfig(unknown_floor_mu=0.0)


def test_conservative_never_goes_below_the_friction_a_peak_context_used():
    # a friction peak the data never approached: std 0.5, mu - 2 std < 0; the car drove there
    # using 0.28, so its lower confidence bound is at least that
    fitted = [(0.9, 0.5, 0.28), (0.9, 0.01, float("nan"))]
    th = unknown_context_theta("conservative", PRIOR, fitted, None, floor_mu=0.3, sigmas=2.0)
    assert th[0] == pytest.approx(0.28)
    # without the used friction the old rule: the floor of 0.05
    th = unknown_context_theta("conservative", PRIOR, [(0.9, 0.5)], None, floor_mu=0.3)
    assert th[0] == pytest.approx(0.05)


def test_a_stated_floor_is_never_undercut_by_a_low_fit():
    # the public mapping's grass: fitted 0.26 +- 0.02 for 0.30; its lower bound 0.22 is below
    # the operator's stated lowest friction of the course (0.3)
    fitted = [(0.26, 0.02, 0.21), (0.6, 0.05, 0.4)]
    low = unknown_context_theta("conservative", PRIOR, fitted, None, floor_mu=0.3, sigmas=2.0)
    assert low[0] == pytest.approx(0.22)
    stated = unknown_context_theta(
        "conservative", PRIOR, fitted, None, floor_mu=0.3, sigmas=2.0, floor_stated=True
    )
    assert stated[0] == pytest.approx(0.3)
    np.testing.assert_allclose(stated[0] * stated[1:], PRIOR[0] * PRIOR[1:])  # stiffness kept
    # the estimator: a new context after the low one gets the floor
    params = ford_escort()
    for flag, mu in ((False, 0.22), (True, 0.3)):
        est = ContextEstimator(params, LiveFitConfig(unknown_floor_stated=flag))
        est.add_sample(0.0, np.array([0, 0, 0, 5.0, 0, 0, 0]), [0, 0], [2])
        est._slots[2].estimate = replace(
            est._slots[2].estimate,
            theta=(0.26, params.C_Sf, params.C_Sr),
            theta_std=(0.02, 0, 0),
            fits=1,
        )
        est.add_sample(0.1, np.array([0, 0, 0, 5.0, 0, 0, 0]), [0, 0], [4])  # new, no fit
        assert est.theta_for()[0] == pytest.approx(mu)
