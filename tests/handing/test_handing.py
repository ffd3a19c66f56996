"""What the controller gets: each rule of the handing on synthetic fits and frames with known
answers."""

import math

import numpy as np
import pytest

from pcvfe_drake.estimation.estimate_table import ContextEstimate
from pcvfe_drake.estimation.probe import ProbeState
from pcvfe_drake.handing.config import (
    Conservative,
    HandingConfig,
    LowerBound,
    Prior,
    Probe,
    StatedFloor,
)
from pcvfe_drake.handing.context_state import (
    BACKED_OFF,
    EXPLORING,
    IDENTIFIED,
    UNKNOWN,
    ContextHanding,
    ModelError,
)
from pcvfe_drake.handing.handing import Handing
from pcvfe_drake.vehicle.params import ford_escort

VP = ford_escort()
PRIOR = tuple(VP.theta)
FRAME_S = 0.1


def fit(ident, mu, std=0.01, identifiable=True, used=math.nan, **kw) -> ContextEstimate:
    """A fitted context: ``mu`` +- ``std`` with the car's stiffnesses."""
    return ContextEstimate(
        ident,
        (mu, VP.C_Sf, VP.C_Sr),
        (std, math.nan, math.nan),
        fits=1,
        identifiable=identifiable,
        mu_lower_bound=used,
        **kw,
    )


def handing(**cfg) -> Handing:
    return Handing(HandingConfig(**cfg), PRIOR, VP)


def drive(h: Handing, fits, t: float, ids) -> tuple[list[float], float]:
    """Feed frames ``ids`` (one per ``FRAME_S``); the mu handed after each."""
    mus = []
    for ident in ids:
        t += FRAME_S
        h.observe(t, ident, ident in fits)
        mus.append(float(h.theta(fits)[0]))
    return mus, t


def test_less_friction_is_handed_on_the_first_frame_that_leaves_the_context():
    # brick 0.88 identified; then sand (new, noise frames) entered mid-bend: the first noise
    # frame already hands the unknown value (the stated floor), not brick's 0.88 for the hold
    fits = {1: fit(1, 0.88)}
    h = handing(unknown=StatedFloor(), unidentified=Probe(), floor_mu=0.3)
    mus, t = drive(h, fits, 0.0, [1] * 15)
    assert mus[-1] == pytest.approx(0.88)
    mus, t = drive(h, fits, t, [-1, -1, -1])
    assert mus == pytest.approx([0.3] * 3)
    # brick's id back within the noise hold: its visit goes on, its theta at once
    mus, t = drive(h, fits, t, [1])
    assert mus == pytest.approx([0.88])


def test_the_noise_hold_keeps_only_less_friction():
    # the prior as the unknown value (more than grass): a noise frame keeps grass' 0.3 for the
    # hold, then the unknown value
    fits = {2: fit(2, 0.3)}
    h = handing(unknown=Prior(), noise_hold_s=0.5, confirm_rise_s=0.0)
    _, t = drive(h, fits, 0.0, [2] * 5)
    mus, t = drive(h, fits, t, [-1] * 8)
    assert mus[:5] == pytest.approx([0.3] * 5)
    assert mus[-1] == pytest.approx(PRIOR[0])


def _grass_then(confirm_s: float):
    """Grass (id 2, mu 0.3) driven for 5 s; concrete (id 1, mu 0.6) fitted earlier."""
    fits = {1: fit(1, 0.6), 2: fit(2, 0.3)}
    h = handing(confirm_rise_s=confirm_s, noise_hold_s=1.0, floor_mu=0.3)
    mus, t = drive(h, fits, 0.0, [2] * 50)
    assert mus[-1] == 0.3
    return h, fits, t


def test_more_friction_waits_for_confirmation_and_a_stray_id_is_never_handed():
    # 0.4 s of a transition strip taken for concrete, then a terrain never seen (noise)
    strip = [1, 1, 1, 1] + [-1] * 25
    h, fits, t = _grass_then(0.0)
    mus, _ = drive(h, fits, t, strip)
    assert mus[:4] == [0.6] * 4  # without confirmation: concrete's mu for the strip
    h, fits, t = _grass_then(1.0)
    mus, _ = drive(h, fits, t, strip)
    assert max(mus) == 0.3  # with it: grass' mu, then the unknown value
    assert mus[-1] == pytest.approx(0.28)  # the conservative value: grass' 0.3 - 2 std
    # a real switch waits confirm_s; back to less friction at once
    h, fits, t = _grass_then(1.0)
    mus, t = drive(h, fits, t, [1] * 15)
    assert mus[:10] == [0.3] * 10 and mus[10:] == [0.6] * 5
    mus, t = drive(h, fits, t, [2] * 3)
    assert mus == [0.3] * 3


def test_a_context_identified_below_the_stated_floor_is_handed_its_own_estimate():
    # grass read 0.215 +- 0.024 with the floor stated 0.3: the floor is a guess
    fits = {0: fit(0, 0.215, std=0.024)}
    h = handing(unknown=StatedFloor(), unidentified=Probe(), floor_mu=0.3)
    _, t = drive(h, fits, 0.0, [0] * 20)
    assert h.theta(fits)[0] == pytest.approx(0.215)
    # and the course has less than the floor: the unknown value follows it
    mus, _ = drive(h, fits, t, [-1] * 20)
    assert mus[-1] == pytest.approx(0.215)
    np.testing.assert_allclose(h.unknown(fits)[0] * h.unknown(fits)[1:], VP.mu * VP.theta[1:])
    # a context not yet identifiable still starts exploring at the floor
    fits[3] = fit(3, 0.8, std=0.3, identifiable=False, used=0.2)
    assert h.context_theta(fits[3])[0] == pytest.approx(0.3)
    # a fit that is not identified is not evidence of a lower course
    fits = {0: fit(0, 0.215, std=0.2, identifiable=False, used=0.1)}
    assert h.unknown(fits)[0] == pytest.approx(0.3)


def test_conservative_uses_the_lowest_lower_bound_but_never_below_the_friction_used():
    fits = {0: fit(0, 0.6, std=0.01), 1: fit(1, 0.45, std=0.05), 2: fit(2, 0.8, std=math.nan)}
    h = handing(unknown=Conservative(sigmas=2.0), floor_mu=0.5)
    th = h.unknown(fits)
    np.testing.assert_allclose(th[0], 0.35)
    np.testing.assert_allclose(th[0] * th[1:], VP.mu * VP.theta[1:])  # stiffness kept
    peak = {0: fit(0, 0.9, std=0.5, used=0.28, mu_is_peak=True)}
    assert handing(floor_mu=0.3).unknown(peak)[0] == pytest.approx(0.28)


def test_model_error_grows_away_from_the_calibrated_frictions():
    err = ModelError(0.11, (0.3, 0.8))
    assert err.handed_mu(0.6) == 0.6  # inside: the estimate as it is
    # brick fitted 1.05: 1.05 / 0.8 times the budget; what the growth adds to the error's
    # 95 % bound is handed off
    grown = 0.11 * 1.05 / 0.8
    expected = 1.05 - 1.96 * 1.05 * (grown - 0.11)
    assert err.handed_mu(1.05) == pytest.approx(expected)
    # the handed value keeps the distance to the grown bound's lower end an estimate inside has
    for mu in (0.12, 0.2, 0.29, 0.81, 1.05, 1.5):
        lower = mu * (1 - 1.96 * err.rel_at(mu))
        assert err.handed_mu(mu) - lower == pytest.approx(1.96 * 0.11 * mu)
    assert err.handed_mu(0.2) < 0.2 and err.rel_at(0.2) == pytest.approx(0.11 * 1.5)
    assert ModelError(0.11).handed_mu(1.05) == 1.05  # no calibration known: no growth
    # below the checked friction the grown error is never handed below the friction used
    low = Handing(HandingConfig(), PRIOR, VP, model_error=err)
    assert err.handed_mu(0.12) < 0.1
    assert low.context_theta(fit(0, 0.12, used=0.1))[0] == pytest.approx(0.1)
    assert low.context_theta(fit(0, 0.12))[0] == pytest.approx(max(err.handed_mu(0.12), 0.05))
    h = Handing(HandingConfig(), PRIOR, VP, model_error=err)
    assert h.context_theta(fit(0, 1.05))[0] == pytest.approx(expected)
    assert h.context_theta(fit(0, 1.05, identifiable=False))[0] == 1.05  # !Estimate: the fit


def test_the_handed_mu_rises_with_the_estimate_across_the_calibrated_ends():
    """A higher estimate is never handed less, and a little outside costs a little: the margin
    has a finite slope at both ends of the calibrated frictions (a quadrature sum of the budget
    and the growth would hand an estimate just above ``high`` less than one at ``high``, and
    take a step's worth off just below ``low``)."""
    err = ModelError(0.164, (0.3147, 1.03))
    mus = np.linspace(0.12, 1.6, 2000)
    handed = np.array([err.handed_mu(m) for m in mus])
    assert np.all(np.diff(handed) > 0)
    for end in (0.3147, 1.03):
        step = 1e-4 * end
        slope_in = err.handed_mu(end) - err.handed_mu(end - step if end > 1 else end + step)
        slope_out = (err.handed_mu(end + step if end > 1 else end - step)) - err.handed_mu(end)
        # outside the slope changes by at most the margin's own rate (1.96 rel per unit of g)
        assert abs(slope_out - slope_in) <= 1.96 * 0.164 * 2 * step + 1e-12
    # 3.5 % below the checked friction costs at most the growth of the bound there
    mu = 0.3147 / 1.035
    assert mu - err.handed_mu(mu) == pytest.approx(1.96 * 0.164 * (0.3147 - mu))
    assert mu - err.handed_mu(mu) < 0.005


def test_each_context_has_one_state():
    h = handing(unidentified=Probe())
    assert h.state(ContextEstimate(0, PRIOR, (math.nan,) * 3)) == UNKNOWN
    assert h.state(fit(0, 0.5)) == IDENTIFIED
    assert h.state(fit(1, 0.5, identifiable=False)) == EXPLORING
    h.contexts[1] = ContextHanding(probe=ProbeState(mu=0.4, backoffs=1, backed_off=True))
    assert h.state(fit(1, 0.5, identifiable=False)) == BACKED_OFF
    assert h.probe_of(1).backoffs == 1 and handing().probe_of(1) is None


def test_lower_bound_hands_the_friction_used_at_least_the_floor():
    h = handing(unidentified=LowerBound(), floor_mu=0.3)
    assert h.context_theta(fit(0, 0.9, std=0.3, identifiable=False, used=0.5))[0] == 0.5
    assert h.context_theta(fit(0, 0.9, std=0.3, identifiable=False, used=0.2))[0] == 0.3
    assert h.context_theta(fit(0, 0.25, std=0.3, identifiable=False, used=0.2))[0] == 0.25


def test_a_level_before_the_fit_has_the_stiffness_the_cars_model_states():
    """Under a mapping whose whole tyre follows the friction (``peak_tyre.k_s = 1``) a level
    handed without a fit has the small-slip stiffness of that friction, so the probe judges a
    soft tyre's slip angles by its own stiffness; with ``k_s = 0`` it keeps the prior's."""
    from pcvfe_drake.handing.unknown import with_friction
    from pcvfe_drake.models.effect_model import load_model_file, vehicle_model_path

    stiffness = PRIOR[0] * np.array(PRIOR[1:])
    kept = with_friction(PRIOR, 0.3)
    np.testing.assert_allclose(kept[0] * kept[1:], stiffness)
    soft = with_friction(PRIOR, 0.3, 1.0)
    np.testing.assert_allclose(soft[0] * soft[1:], stiffness * 0.3 / PRIOR[0])
    half = with_friction(PRIOR, 0.3, 0.5)
    np.testing.assert_allclose(half[0] * half[1:], stiffness * (0.3 / PRIOR[0]) ** 0.5)
    # the same law twice: the floor's theta raised to a level is the prior's at that level
    np.testing.assert_allclose(with_friction(soft, 0.42, 1.0), with_friction(PRIOR, 0.42, 1.0))
    for law in (0.0, 1.0):
        h = Handing(HandingConfig(floor_mu=0.3, unknown=StatedFloor()), PRIOR, VP,
                    stiffness_law=law)  # fmt: skip
        th = h.unknown({})
        np.testing.assert_allclose(th[0] * th[1:], stiffness * (0.3 / PRIOR[0]) ** law)
    laws = {
        m: load_model_file(vehicle_model_path("ford_escort", "mb", m)).stiffness_law
        for m in ("lateral_peak", "peak_and_stiffness")
    }
    assert laws == {"lateral_peak": 0.0, "peak_and_stiffness": 1.0}
