"""roll_camber: the tyre_offsets hook against the separately written truth, the null value,
the cornering direction, and the loop on planted and clean data."""

from __future__ import annotations

import numpy as np
import pytest
from drive_logs import proof_logs
from workbench_states import TYRE_LAWS, random_states, truth_columns

from pcvfe_drake.models.data import prepare
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.models.tyre_effects import ROLL_SIGN_WIDTH_MPS2, RollCamber
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth
from pcvfe_drake.workbench.ranking import Workbench
from pcvfe_drake.workbench.report import diagnose
from pcvfe_drake.workbench.selection import try_effect

CAMBER = (-0.037, 0.03, 0.0027)


@pytest.mark.parametrize(
    "effects, theta, truth",
    TYRE_LAWS,
)
def test_rates_match_the_separately_written_truth(effects, theta, truth):
    vp = ford_escort()
    s, u = random_states(12)
    n = s.shape[0]
    tr = truth_columns(n, cam_f0=CAMBER[0], cam_f1=CAMBER[1], cam_s0=CAMBER[2], **truth)
    expected = synth._truth_rates(vp, tr, s, u[:, 0], u[:, 1])
    model = WorkbenchModel(vp).with_effects(*effects, "roll_camber")
    assert model.param_names[-3:] == ["roll_camber.f0", "roll_camber.f1", "roll_camber.s0"]
    base, eff = model._unpack(np.tile([*theta, *CAMBER], (n, 1)), np.zeros(n, int))
    assert np.allclose(model.rhs(s[:, :7], u, base, eff), expected[:, :7], atol=1e-9)
    # and the offsets matter: the truth without them differs
    plain = synth._truth_rates(vp, truth_columns(n, **truth), s, u[:, 0], u[:, 1])
    assert np.min(np.abs(plain[:, 6] - expected[:, 6])) > 1e-4


def test_null_is_the_baseline_and_offsets_follow_the_cornering_direction():
    vp = ford_escort()
    s, u = random_states(12)
    n = s.shape[0]
    base_model = WorkbenchModel(vp)
    b0, e0 = base_model._unpack(np.full((n, 1), vp.mu), np.zeros(n, int))
    model = base_model.with_effects("roll_camber")
    b1, e1 = model._unpack(np.tile([vp.mu, 0.0, 0.0, 0.0], (n, 1)), np.zeros(n, int))
    ref = base_model.rhs(s[:, :7], u, b0, e0)
    assert np.max(np.abs(model.rhs(s[:, :7], u, b1, e1) - ref)) < 1e-12
    # f0 alone: a side force of f0 x the axle loads, signed by tanh(v psi_dot / 0.5 m/s^2),
    # equal per unit load on both axles, so it adds to beta's rate and (at the static loads)
    # nothing to the yaw moment
    x = np.zeros((3, 7))
    x[:, 3] = 10.0
    x[:, 5] = [0.2, -0.2, 0.0]  # a left bend, a right bend, straight
    b, e = model._unpack(np.tile([vp.mu, 0.05, 0.0, 0.0], (3, 1)), np.zeros(3, int))
    b0, e0 = base_model._unpack(np.full((3, 1), vp.mu), np.zeros(3, int))
    zero = np.zeros((3, 2))
    diff = model.rhs(x, zero, b, e) - base_model.rhs(x, zero, b0, e0)
    turn = np.tanh(2.0 / ROLL_SIGN_WIDTH_MPS2)
    expected = 0.05 * vp.g * turn / 10.0
    assert diff[:, 6] == pytest.approx([expected, -expected, 0.0], rel=1e-9, abs=1e-12)
    assert np.max(np.abs(diff[:, 5])) < 1e-9
    a, sign = RollCamber.direction(x)
    assert a == pytest.approx([2.0, -2.0, 0.0]) and sign[2] == 0.0


def test_the_slip_shift_moves_the_curve_and_not_the_peak():
    """With peak_tyre, s0 shifts the force curve along the slip: more force at small slip in
    the cornering direction, the same largest force."""
    vp = ford_escort()
    model = WorkbenchModel(vp).with_effects("peak_tyre", "roll_camber")
    alpha = np.linspace(0.0, 0.3, 3001)
    n = alpha.size
    x = np.zeros((n, 7))
    x[:, 3] = 10.0
    x[:, 5] = 0.5  # 5 m/s^2 to the left: the shift pushes toward +y
    x[:, 6] = -alpha  # rear slip = front slip = alpha (delta 0, psi_dot small against v)
    out = []
    for s0 in (0.0, 0.003):
        b, e = model._unpack(np.tile([0.45, 0.0, 0.0, 0.0, s0], (n, 1)), np.zeros(n, int))
        out.append(model.rhs(x, np.zeros((n, 2)), b, e)[:, 6] + x[:, 5])
    small = slice(1, 200)
    assert np.all(out[1][small] > out[0][small])
    assert np.max(out[1]) == pytest.approx(np.max(out[0]), rel=1e-4)


@pytest.fixture(scope="module")
def logs(run_cache):
    """The planted truth ("planted") and the same car without it ("clean"), 90 s logs."""
    return proof_logs(run_cache, "roll_camber")


def test_loop_finds_the_planted_roll_camber(logs):
    """On a linear tyre the step force f0 and the slip shift s0 are one force (mu C_S Fz s0
    against f0 Fz): what the data fix is the camber thrust f1 and the step's small-slip force
    f0 + mu C_S s0."""
    report, _ = diagnose(prepare(logs["planted"], "roll_camber"))
    assert [s["name"] for s in report["selected"]] == ["roll_camber"]
    params = report["final"]["params"]
    f0, f1, s0 = synth.PLANTED["roll_camber"][0].roll_camber
    got = {k: params[f"roll_camber.{k}"]["value"] for k in ("f0", "f1", "s0")}
    assert abs(got["f1"] - f1) <= 0.15 * abs(f1), got
    mu = params["mu"]["value"]
    assert abs(mu - ford_escort().mu) <= 0.02
    step = got["f0"] + mu * ford_escort().C_Sf * got["s0"]
    assert abs(step - (f0 + mu * ford_escort().C_Sf * s0)) <= 0.35 * abs(f0), got
    final = report["final"]
    assert final["heldout_multistep_error"] <= 1.2 * final["noise_floor"], final
    assert report["verdict"]["kind"] == "explained", report["verdict"]["text"]


def test_clean_log_does_not_select_roll_camber(logs):
    wb = Workbench(prepare(logs["clean"], "clean"))
    trial = try_effect(wb, wb.baseline, wb.baseline_eval, "roll_camber", n_tests=1)
    assert not trial.significant, (trial.p_value, trial.drop)
    assert trial.p_value > 0.01
