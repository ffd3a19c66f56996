"""The peak_tyre effect: the base mu IS the friction peak, the stiffness follows mu by k_s."""

from __future__ import annotations

import numpy as np
import pytest
from drive_logs import proof_logs
from lazy_diagnoses import LazyDiagnoses

from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.models.tyre_effects import MF_SHAPE
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import Effect, StepContext, get_effect, known_effects, synth


def _ctx(mu, n):
    vp = ford_escort()
    return StepContext(np.zeros((n, 7)), np.zeros((n, 0)), np.zeros(n), np.zeros(n), vp, mu=mu)


def test_friction_is_peak_flag():
    assert get_effect("peak_tyre").friction_is_peak is True
    assert Effect.friction_is_peak is False
    others = [n for n in known_effects() if n != "peak_tyre"]
    assert not any(get_effect(n).friction_is_peak for n in others)


@pytest.mark.parametrize("mu", [0.3, 0.7, 1.2])
@pytest.mark.parametrize("k_s", [0.0, 0.5, 1.0])
def test_largest_force_is_mu_fz_and_small_slip_stiffness_follows_k_s(mu, k_s):
    vp = ford_escort()
    e = get_effect("peak_tyre")
    alpha = np.linspace(-0.6, 0.6, 24001)
    n = alpha.size
    fz = np.full(n, 4000.0)
    c_alpha = mu * vp.C_Sf * fz  # what the model passes: base mu x C_S x Fz
    fy = e.tire(alpha, fz, c_alpha, {"k_s": np.full(n, k_s)}, _ctx(np.full(n, mu), n))
    assert np.max(fy) == pytest.approx(mu * 4000.0, rel=1e-6)
    assert np.min(fy) == pytest.approx(-mu * 4000.0, rel=1e-6)
    # beyond the peak the force falls toward D sin(C pi / 2)
    assert fy[-1] < 0.99 * mu * 4000.0
    # small-slip slope: C_S Fz mu_nom (mu / mu_nom)^k_s
    small = np.array([1e-6])
    one = e.tire(small, fz[:1], c_alpha[:1], {"k_s": np.array([k_s])}, _ctx(np.array([mu]), 1))
    expected = vp.C_Sf * 4000.0 * vp.mu * (mu / vp.mu) ** k_s
    assert one[0] / 1e-6 == pytest.approx(expected, rel=1e-6)


def test_model_passes_the_base_mu_and_integrates_with_the_tyre_stiffness():
    vp = ford_escort()
    model = WorkbenchModel(vp).with_effects("peak_tyre")
    base, eff = model._unpack(np.array([[0.3, 0.0]]), np.zeros(1, int))
    # with k_s = 0 the stiffness stays nominal although mu is 0.3: the step must follow it
    step_peak = model.stable_step(base, np.array([5.0]), eff)
    lin = WorkbenchModel(vp)
    base_lin, eff_lin = lin._unpack(np.array([[vp.mu]]), np.zeros(1, int))
    assert step_peak == pytest.approx(lin.stable_step(base_lin, np.array([5.0]), eff_lin))
    assert MF_SHAPE == pytest.approx(1.35)
    # a peak far above the nominal friction at the same small-slip stiffness (the peak
    # evidence's tyre "without a peak") integrates with the same step, not a 1000x smaller one
    high, eff_high = model._unpack(np.array([[300.0, 0.0]]), np.zeros(1, int))
    assert model.stable_step(high, np.array([5.0]), eff_high) == pytest.approx(step_peak)


def test_planted_magic_formula_truth_matches_the_effect():
    """The synthetic truth (written separately in synth) and the effect agree force for force."""
    import math

    vp = ford_escort()
    n = 7
    rng = np.random.default_rng(0)
    s = np.zeros((n, 8))
    s[:, 3] = rng.uniform(8.0, 20.0, n)
    s[:, 5] = rng.normal(0.0, 0.3, n)
    s[:, 6] = rng.normal(0.0, 0.05, n)
    s[:, 2] = s[:, 7] = rng.normal(0.0, 0.05, n)
    keys = dict(
        mu=vp.mu, CdA=0.0, c_rr=0.0, steer_tau=0.0, mu_peak=math.inf, gx=0.0, gy=0.0,
        p_max_kw=math.inf, mu_speed_slope=0.0, mu_load_sens=0.0, mf_peak=0.6,
        mf_shape=MF_SHAPE, mf_exp=0.4, k_f=1.0, k_r=1.0, m_rot=0.0,
        ff_drive=0.0, ff_brake=0.0, ff_drag=0.0,
    )  # fmt: skip
    tr = {k: np.full(n, v) for k, v in keys.items()}
    u = np.zeros((n, 2))
    truth = synth._truth_rates(vp, tr, s, u[:, 0], u[:, 1])[:, :7]
    model = WorkbenchModel(vp).with_effects("peak_tyre")
    base, eff = model._unpack(np.tile([0.6, 0.4], (n, 1)), np.zeros(n, int))
    assert np.allclose(model.rhs(s[:, :7], u, base, eff), truth, atol=1e-9)


@pytest.fixture(scope="module")
def planted_reports(run_cache):
    """The peak tyre's truth ("mf") and the brush tyre's ("brush"), 90 s logs."""
    return LazyDiagnoses(proof_logs(run_cache, "peak_tyre"), run_cache, "peak-tyre-")


def test_loop_selects_the_peak_tyre_and_reads_mu_as_the_peak(planted_reports):
    """Planted: a magic-formula tyre, peak 0.7, stiffness nominal (exponent 0), 90 s log."""
    report = planted_reports["mf"]
    assert [s["name"] for s in report["selected"]] == ["peak_tyre"]
    params = report["final"]["params"]
    assert abs(params["mu"]["value"] - 0.7) <= 0.03 * 0.7, params  # mu IS the peak
    assert abs(params["peak_tyre.k_s"]["value"] - 0.0) <= 0.1, params
    assert not params["peak_tyre.k_s"]["at_bound"]
    final = report["final"]
    assert final["heldout_multistep_error"] <= 1.2 * final["noise_floor"], final
    assert report["verdict"]["kind"] == "explained", report["verdict"]["text"]
    # the linear baseline reads a friction that is neither the peak nor the nominal
    assert abs(report["baseline"]["params"]["mu"]["value"] - 0.7) > 0.05


def test_brush_truth_still_selects_tire_saturation_not_the_peak_tyre(planted_reports):
    report = planted_reports["brush"]
    assert [s["name"] for s in report["selected"]] == ["tire_saturation"]
