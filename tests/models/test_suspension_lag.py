"""suspension_lag: the pitch mode's exact transition, equations against the separately written
truth, the null value, and the loop on planted and clean data."""

from __future__ import annotations

import numpy as np
import pytest
from drive_logs import proof_logs
from scipy.linalg import expm
from workbench_states import random_states, truth_columns

from pcvfe_drake.models.chassis_effects import TAU_MIN_S, mode_transition
from pcvfe_drake.models.data import prepare
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth
from pcvfe_drake.workbench.ranking import Workbench
from pcvfe_drake.workbench.report import diagnose
from pcvfe_drake.workbench.selection import try_effect


@pytest.mark.parametrize(
    "tau, zeta", [(0.125, 0.2), (0.1, 1.0), (0.1, 1.0 - 1e-7), (0.08, 1.7), (0.3, 0.05)]
)
def test_mode_transition_is_the_matrix_exponential(tau, zeta):
    w = 1.0 / tau
    expected = expm(np.array([[0.0, 1.0], [-w * w, -2.0 * zeta * w]]) * 0.05)
    got = np.array(mode_transition(tau, zeta, 0.05), dtype=float).reshape(2, 2)
    assert np.allclose(got, expected, atol=1e-12, rtol=1e-9)


@pytest.mark.parametrize(
    "effects, theta, truth",
    [
        ((), [ford_escort().mu], {}),
        (("drag", "peak_tyre"), [0.6, 0.75, 0.3], {"CdA": 0.75, "mf_peak": 0.6, "mf_exp": 0.3}),
    ],
)
def test_rates_match_the_separately_written_truth(effects, theta, truth):
    vp = ford_escort()
    s, u = random_states(pitch=True)
    n = s.shape[0]
    tr = truth_columns(n, pitch_tau=0.125, pitch_zeta=0.2, **truth)
    expected = synth._truth_rates(vp, tr, s, u[:, 0], u[:, 1])
    model = WorkbenchModel(vp).with_effects(*effects, "suspension_lag")
    assert model.param_names[-2:] == ["suspension_lag.tau", "suspension_lag.zeta"]
    base, eff = model._unpack(np.tile([*theta, 0.125, 0.2], (n, 1)), np.zeros(n, int))
    z = np.concatenate([s[:, :7], s[:, 8:10]], axis=1)
    assert np.allclose(model.rhs(z, u, base, eff), np.delete(expected, 7, axis=1), atol=1e-9)
    # the loads follow q, not a_x: moving q moves the yaw rate's rate
    z2 = z.copy()
    z2[:, 7] += 1.0
    assert np.all(np.abs(model.rhs(z2, u, base, eff)[:, 5] - model.rhs(z, u, base, eff)[:, 5]) > 0)


def test_tau_zero_is_the_baseline_and_the_model_is_continuous_in_tau():
    vp = ford_escort()
    s, u = random_states(pitch=True)
    n = s.shape[0]
    base_model = WorkbenchModel(vp)
    b0, e0 = base_model._unpack(np.full((n, 1), vp.mu), np.zeros(n, int))
    model = base_model.with_effects("suspension_lag")
    z = np.concatenate([s[:, :7], s[:, 8:10]], axis=1)
    ref = base_model.rhs(s[:, :7], u, b0, e0)
    b1, e1 = model._unpack(np.tile([vp.mu, 0.0, 0.3], (n, 1)), np.zeros(n, int))
    assert np.max(np.abs(model.rhs(z, u, b1, e1)[:, :7] - ref)) < 1e-12
    small = []
    for tau in (1e-3 * TAU_MIN_S, 1e-2 * TAU_MIN_S):
        b, e = model._unpack(np.tile([vp.mu, tau, 0.3], (n, 1)), np.zeros(n, int))
        small.append(np.max(np.abs(model.rhs(z, u, b, e)[:, :7] - ref)))
    assert small[0] < 0.2 * small[1]  # linear in tau near 0: no jump
    # and a rollout at tau = 0 is the baseline's
    log = synth.simulate_truths([synth.Truth()], duration_s=25.0, seed=3, substeps=2)[0]
    data = prepare(log, "clean")
    starts = np.arange(20, 400, 40)
    base_roll = base_model.simulate([vp.mu], data, starts, 20)
    roll = model.simulate([vp.mu, 0.0, 0.3], data, starts, 20)
    assert np.max(np.abs(roll[:, :, :7] - base_roll)) < 1e-12


def test_steady_state_is_the_instant_transfer_and_initial_states_follow_the_log():
    vp = ford_escort()
    model = WorkbenchModel(vp).with_effects("suspension_lag")
    effect = model.effects[0]
    # a log braking at a constant -0.5 m/s^2: the mode settles on a_x = -0.5
    n = 500
    t = np.arange(n) * 0.05
    df = synth._to_log(
        np.column_stack(
            [20.0 * t - 0.25 * t**2, 0 * t, 0 * t, 20.0 - 0.5 * t, 0 * t, 0 * t, 0 * t]
        ),
        np.zeros(n),
        np.full(n, -0.5),
        0.05,
        None,
        0,
    )
    data = prepare(df, "braking")
    q = effect.initial_states(
        data, np.array([400, 490]), {"tau": np.full(2, 0.125), "zeta": np.full(2, 0.2)}
    )
    assert np.allclose(q[:, 0], -0.5, atol=1e-6)
    assert np.allclose(q[:, 1], 0.0, atol=1e-5)


@pytest.fixture(scope="module")
def logs(run_cache):
    """The planted truth ("planted") and the same car without it ("clean"), 90 s logs."""
    return proof_logs(run_cache, "suspension_lag")


def test_loop_finds_the_planted_pitch_mode(logs):
    report, _ = diagnose(prepare(logs["planted"], "suspension_lag"))
    assert [s["name"] for s in report["selected"]] == ["suspension_lag"]
    params = report["final"]["params"]
    truth = synth.PLANTED["suspension_lag"][0].pitch_mode
    tau, zeta = params["suspension_lag.tau"], params["suspension_lag.zeta"]
    assert abs(tau["value"] - truth[0]) <= 0.05 * truth[0], tau
    assert abs(zeta["value"] - truth[1]) <= 0.15 * truth[1], zeta
    assert abs(params["mu"]["value"] - ford_escort().mu) <= 0.05
    final = report["final"]
    assert final["heldout_multistep_error"] <= 1.2 * final["noise_floor"], final
    assert report["verdict"]["kind"] == "explained", report["verdict"]["text"]


def test_clean_log_does_not_select_the_pitch_mode(logs):
    wb = Workbench(prepare(logs["clean"], "clean"))
    trial = try_effect(wb, wb.baseline, wb.baseline_eval, "suspension_lag", n_tests=1)
    assert not trial.significant, (trial.p_value, trial.drop)
    assert trial.p_value > 0.01
