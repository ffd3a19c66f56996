"""axle_stiffness and rotating_inertia: equations, null values, and the loop on planted data."""

from __future__ import annotations

import numpy as np
import pytest
from drive_logs import proof_logs
from lazy_diagnoses import LazyDiagnoses
from workbench_states import random_states, truth_columns

from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth


@pytest.mark.parametrize(
    "effects, theta_effects, truth",
    [
        (("axle_stiffness",), [0.9, 1.2], {"k_f": 0.9, "k_r": 1.2}),
        (("rotating_inertia",), [60.0], {"m_rot": 60.0}),
        (
            ("wheel_force_steer", "rotating_inertia"),
            [1.0, 0.76, 0.8, 50.0],
            {"ff_drive": 1.0, "ff_brake": 0.76, "ff_drag": 0.8, "m_rot": 50.0},
        ),
        (
            ("peak_tyre", "axle_stiffness"),
            [0.3, 0.9, 1.2],
            {"mf_peak": 0.6, "mf_exp": 0.3, "k_f": 0.9, "k_r": 1.2},
        ),
    ],
)
def test_effects_match_the_separately_written_truth(effects, theta_effects, truth):
    vp = ford_escort()
    s, u = random_states()
    n = s.shape[0]
    mu = truth.get("mf_peak", vp.mu)
    expected = synth._truth_rates(vp, truth_columns(n, **truth), s, u[:, 0], u[:, 1])[:, :7]
    model = WorkbenchModel(vp).with_effects(*effects)
    base, eff = model._unpack(np.tile([mu, *theta_effects], (n, 1)), np.zeros(n, int))
    assert np.allclose(model.rhs(s[:, :7], u, base, eff), expected, atol=1e-9)


@pytest.mark.parametrize(
    "name, null",
    [
        ("axle_stiffness", [1.0, 1.0]),
        ("rotating_inertia", [0.0]),
        ("wheel_force_steer", [0.0, 0.0, 0.0]),
    ],
)
def test_null_values_give_the_baseline(name, null):
    vp = ford_escort()
    s, u = random_states()
    n = s.shape[0]
    base_model = WorkbenchModel(vp)
    b0, e0 = base_model._unpack(np.full((n, 1), vp.mu), np.zeros(n, int))
    model = base_model.with_effects(name)
    b1, e1 = model._unpack(np.tile([vp.mu, *null], (n, 1)), np.zeros(n, int))
    diff = model.rhs(s[:, :7], u, b1, e1) - base_model.rhs(s[:, :7], u, b0, e0)
    assert np.max(np.abs(diff)) < 1e-12


def test_axle_stiffness_leaves_the_peak_of_the_peak_tyre():
    vp = ford_escort()
    model = WorkbenchModel(vp).with_effects("peak_tyre", "axle_stiffness")
    n = 2001
    x = np.zeros((n, 7))
    x[:, 3] = 15.0
    x[:, 6] = np.linspace(-0.4, 0.4, n)  # slip angles on both axles
    base, eff = model._unpack(np.tile([0.5, 0.0, 1.8, 1.8], (n, 1)), np.zeros(n, int))
    z = model.rhs(x, np.zeros((n, 2)), base, eff)
    # total lateral force / (m g) = v (beta' + r) / g with r = 0 never exceeds the peak 0.5
    lateral = 15.0 * z[:, 6] / vp.g
    assert np.max(np.abs(lateral)) == pytest.approx(0.5, rel=2e-3)


@pytest.fixture(scope="module")
def planted(run_cache):
    return LazyDiagnoses(proof_logs(run_cache, "chassis"), run_cache, "chassis-")


@pytest.mark.parametrize("name", ["axle_stiffness", "rotating_inertia", "wheel_force_steer"])
def test_loop_finds_the_planted_chassis_effect(planted, name):
    report = planted[name]
    assert [s["name"] for s in report["selected"]] == [name]
    truth, _, _ = synth.PLANTED[name]
    params = report["final"]["params"]
    if name == "axle_stiffness":
        expected = dict(zip(("k_f", "k_r"), truth.axle_stiffness, strict=True))
    elif name == "rotating_inertia":
        expected = {"m_rot": truth.rotating_mass_kg}
    else:
        # the cornering drag is pinned; the drive/brake shares only to their stated
        # uncertainty (+-0.2 to 0.3 on a 90 s log: F_xf sin(delta) is a small force)
        expected = {"k_drag": truth.front_forces[2]}
        for key, value in zip(("s_drive", "s_brake"), truth.front_forces[:2], strict=True):
            fitted = params[f"{name}.{key}"]
            assert abs(fitted["value"] - value) <= 2.0 * fitted["std"] < 0.6, (key, fitted)
    for key, value in expected.items():
        fitted = params[f"{name}.{key}"]["value"]
        assert abs(fitted - value) <= 0.05 * value, (key, fitted, value)
    assert abs(params["mu"]["value"] - ford_escort().mu) <= 0.05
    final = report["final"]
    assert final["heldout_multistep_error"] <= 1.2 * final["noise_floor"], final
    assert report["verdict"]["kind"] == "explained", report["verdict"]["text"]
