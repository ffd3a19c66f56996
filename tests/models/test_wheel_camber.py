"""wheel_camber: the tire_offsets and wheel_slips hooks and the roll state against the
separately written truth, the null value, each wheel's sign, and the loop on planted and
clean data."""

from __future__ import annotations

import numpy as np
import pytest
from drive_logs import proof_logs
from workbench_states import TYRE_LAWS, random_states, truth_columns

from pcvfe_drake.models.data import prepare
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.models.tyre_effects import WHEEL_SIGN_WIDTH_MPS2, WheelCamber
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth
from pcvfe_drake.workbench.ranking import Workbench
from pcvfe_drake.workbench.report import diagnose
from pcvfe_drake.workbench.selection import try_effect

CAMBER = (-0.037, 0.0027, 0.39, -0.095, 0.08)
COLUMNS = dict(zip(("wcam_f0", "wcam_s0", "wcam_kf", "wcam_kr", "wcam_tau"), CAMBER, strict=True))


def camber_states(n: int = 12, seed: int = 0):
    """Random states (width 11: the pitch mode's two and the roll's lateral acceleration)
    whose roll and longitudinal acceleration make the wheels' signs disagree in some rows."""
    s, u = random_states(n, seed, pitch=True)
    rng = np.random.default_rng(seed + 7)
    s = np.concatenate([s, rng.normal(0.0, 0.6, (n, 1))], axis=1)
    return s, u


@pytest.mark.parametrize("effects, theta, truth", TYRE_LAWS)
@pytest.mark.parametrize("track", [False, True])
def test_rates_match_the_separately_written_truth(effects, theta, truth, track):
    vp = ford_escort()
    s, u = camber_states(12)
    n = s.shape[0]
    extra = {"track_f": 1.39, "track_r": 1.39, "track_k_lt": -0.85} if track else {}
    tr = truth_columns(n, **COLUMNS, **extra, **truth)
    expected = synth._truth_rates(vp, tr, s, u[:, 0], u[:, 1])
    more = ("track_slip",) if track else ()
    model = WorkbenchModel(vp).with_effects(*effects, *more, "wheel_camber")
    names = [f"wheel_camber.{k}" for k in ("f0", "s0", "k_xf", "k_xr", "tau")]
    assert model.param_names[-5:] == names
    assert model.state_names[-1] == "wheel_camber.a_roll"
    row = [*theta, *((1.39, -0.85) if track else ()), *CAMBER]
    base, eff = model._unpack(np.tile(row, (n, 1)), np.zeros(n, int))
    z = np.concatenate([s[:, :7], s[:, 10:11]], axis=1)
    got = model.rhs(z, u, base, eff)
    assert np.allclose(got[:, :7], expected[:, :7], atol=1e-9)
    assert np.allclose(got[:, 7], expected[:, 10], atol=1e-9)
    # and the offsets matter: the truth without them differs
    tr_plain = truth_columns(n, **extra, **truth)
    plain = synth._truth_rates(vp, tr_plain, s, u[:, 0], u[:, 1])
    assert np.max(np.abs(plain[:, 6] - expected[:, 6])) > 1e-3


def test_null_is_the_baseline_and_each_wheel_has_its_sign():
    vp = ford_escort()
    s, u = camber_states(12)
    n = s.shape[0]
    z = np.concatenate([s[:, :7], s[:, 10:11]], axis=1)
    base_model = WorkbenchModel(vp)
    b0, e0 = base_model._unpack(np.full((n, 1), vp.mu), np.zeros(n, int))
    model = base_model.with_effects("wheel_camber")
    null = [vp.mu, 0.0, 0.0, 0.5, -0.2, 0.1]
    b1, e1 = model._unpack(np.tile(null, (n, 1)), np.zeros(n, int))
    ref = base_model.rhs(s[:, :7], u, b0, e0)
    assert np.max(np.abs(model.rhs(z, u, b1, e1)[:, :7] - ref)) < 1e-12
    # f0 alone, the roll at 2 m/s^2 to the left: coasting, both wheels of both axles share
    # the sign (a side force of f0 Fz on each axle); braking at 8 m/s^2 the front wheels'
    # cambers point opposite ways (k_xf a_x = -3.1 against 2 m/s^2: their forces cancel)
    # while the rear ones (k_xr a_x = 0.76) still agree
    x = np.zeros((2, 7))
    x[:, 3] = 10.0
    zz = np.concatenate([x, np.full((2, 1), 2.0)], axis=1)
    uu = np.array([[0.0, 0.0], [0.0, -8.0]])
    b, e = model._unpack(np.tile([vp.mu, 0.05, 0.0, 0.39, -0.095, 0.08], (2, 1)), np.zeros(2, int))
    b0, e0 = base_model._unpack(np.full((2, 1), vp.mu), np.zeros(2, int))
    diff = model.rhs(zz, uu, b, e)[:, :7] - base_model.rhs(x, uu, b0, e0)
    wheelbase = vp.lf + vp.lr
    fzf = vp.m * (vp.g * vp.lr - uu[:, 1] * vp.h) / wheelbase
    fzr = vp.m * (vp.g * vp.lf + uu[:, 1] * vp.h) / wheelbase
    sf = WheelCamber.signs(np.full(2, 2.0), uu[:, 1], 0.39)
    sr = WheelCamber.signs(np.full(2, 2.0), uu[:, 1], -0.095)
    side_f = 0.05 * fzf * 0.5 * (sf[0] + sf[1])
    side_r = 0.05 * fzr * 0.5 * (sr[0] + sr[1])
    assert diff[:, 6] == pytest.approx((side_f + side_r) / (vp.m * 10.0), rel=1e-9)
    assert sf[0][0] == pytest.approx(np.tanh(2.0 / WHEEL_SIGN_WIDTH_MPS2))
    assert abs(0.5 * (sf[0][1] + sf[1][1])) < 1e-6 and 0.5 * (sr[0][1] + sr[1][1]) > 0.99
    # the roll state follows the model's lateral acceleration with the lag tau
    a_lat = (model.rhs(zz, uu, b, e)[:, 6] + zz[:, 5]) * 10.0
    assert model.rhs(zz, uu, b, e)[:, 7] == pytest.approx((a_lat - 2.0) / 0.08, rel=1e-9)


def test_initial_state_is_the_lagged_lateral_acceleration():
    """At a window start the roll state is the lag of the log's v psi_dot, held per step."""
    frames = synth.simulate_truths([synth.Truth()], duration_s=25.0, seed=3, substeps=2)
    data = prepare(frames[0], "lag")
    a = data.x[:, 3] * data.x[:, 5]
    tau = 0.08
    e = np.exp(-data.dt / tau)
    expected = np.empty(data.n)
    expected[0] = a[0]
    for k in range(1, data.n):
        expected[k] = e * expected[k - 1] + (1.0 - e) * a[k - 1]
    starts = np.array([0, 5, 60, data.n - 1])
    p = {"tau": np.full(starts.size, tau)}
    got = WheelCamber().initial_states(data, starts, p)[:, 0]
    assert got == pytest.approx(expected[starts], abs=1e-9)


@pytest.fixture(scope="module")
def logs(run_cache):
    """The planted truth ("planted") and the same car without it ("clean"), 90 s logs."""
    return proof_logs(run_cache, "wheel_camber")


def test_loop_finds_the_planted_wheel_camber(logs):
    """Selected alone (roll_camber, the per-axle form, is not taken with it). On a linear
    tyre the step force f0 and the slip shift s0 are one force: what the data fix is the
    small-slip step f0 + mu C_S s0, and the front wheels' pitch coefficient k_xf."""
    report, _ = diagnose(prepare(logs["planted"], "wheel_camber"))
    assert [s["name"] for s in report["selected"]] == ["wheel_camber"]
    params = report["final"]["params"]
    f0, s0, k_xf, _, tau = synth.PLANTED["wheel_camber"][0].wheel_camber
    got = {k: params[f"wheel_camber.{k}"]["value"] for k in ("f0", "s0", "k_xf", "tau")}
    mu = params["mu"]["value"]
    assert abs(mu - ford_escort().mu) <= 0.02
    step = got["f0"] + mu * ford_escort().C_Sf * got["s0"]
    assert abs(step - (f0 + mu * ford_escort().C_Sf * s0)) <= 0.15 * abs(f0), got
    assert abs(got["k_xf"] - k_xf) <= 0.15 * k_xf, got
    assert abs(got["tau"] - tau) <= 0.25 * tau, got
    final = report["final"]
    assert final["heldout_multistep_error"] <= 1.2 * final["noise_floor"], final
    assert report["verdict"]["kind"] == "explained", report["verdict"]["text"]


def test_clean_log_does_not_select_wheel_camber(logs):
    wb = Workbench(prepare(logs["clean"], "clean"))
    trial = try_effect(wb, wb.baseline, wb.baseline_eval, "wheel_camber", n_tests=1)
    assert not trial.significant, (trial.p_value, trial.drop)
    assert trial.p_value > 0.01
