"""Tracking NMPC core: discretisation, QP assembly, fallback, short closed loops."""

import copy
import dataclasses

import numpy as np
import pytest
import scipy.linalg

from pcvfe_drake.control.closed_loop import simulate_closed_loop
from pcvfe_drake.control.course import initial_state, load_course
from pcvfe_drake.control.nmpc import NmpcConfig, NmpcController
from pcvfe_drake.control.prediction_model import discretize, expm_batched, ks_jacobians
from pcvfe_drake.control.reference_qp import dense_qp
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import DELTA, PSI, PSI_DOT, SX, SY, V, st_jacobians


@pytest.fixture(scope="module")
def course():
    return load_course("slalom")


@pytest.fixture(scope="module")
def params():
    return ford_escort()


CFG = NmpcConfig()  # no wall-clock limit by default: deterministic on a busy machine


def offset_start(course, params, s_m=20.0, lateral_m=0.0, speed=5.0):
    x = initial_state(course, params, speed, s_m)
    h = course.sample(s_m)[2]
    x[SX] += -np.sin(h) * lateral_m
    x[SY] += np.cos(h) * lateral_m
    return x


def test_expm_batched_matches_scipy(params):
    rng = np.random.default_rng(1)
    m = rng.normal(size=(5, 10, 10)) * np.array([0.1, 1.0, 5.0, 20.0, 0.0])[:, None, None]
    ref = np.stack([scipy.linalg.expm(a) for a in m])
    np.testing.assert_allclose(expm_batched(m), ref, rtol=1e-11, atol=1e-12)


def test_discretize_is_the_exact_solution_of_the_linear_model(params):
    # Stiff ST linearisation at 1 m/s: integrate dx' = A dx + B du + f with tiny RK4 steps.
    x = np.array([[1.0, 2.0, 0.1, 1.0, 0.3, 0.2, 0.05]])
    u = np.array([[0.1, 0.4]])
    f, A, B, _ = st_jacobians(x, u, params)
    dt = 0.05
    Ad, Bd, g = discretize(f, A, B, dt)
    dx0 = np.array([0.1, -0.2, 0.01, 0.3, 0.02, -0.1, 0.01])
    du = np.array([0.05, -0.5])

    def rhs(d):
        return A[0] @ d + B[0] @ du + f[0]

    d = dx0.copy()
    h = dt / 2000
    for _ in range(2000):
        k1 = rhs(d)
        k2 = rhs(d + h / 2 * k1)
        k3 = rhs(d + h / 2 * k2)
        k4 = rhs(d + h * k3)
        d = d + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(Ad[0] @ dx0 + Bd[0] @ du + g[0], d, rtol=1e-9, atol=1e-11)


def test_kinematic_model_jacobians_match_finite_differences(params):
    rng = np.random.default_rng(2)
    x = np.column_stack(
        [rng.normal(size=4), rng.normal(size=4), rng.uniform(-0.3, 0.3, 4), rng.uniform(1, 8, 4)]
        + [rng.normal(size=4) * 0.3 for _ in range(3)]
    )
    u = np.column_stack([rng.uniform(-0.2, 0.2, 4), rng.uniform(-2, 2, 4)])
    f, A, B = ks_jacobians(x, u, params, 0.1)
    eps = 1e-6
    for i in range(7):
        e = np.zeros(7)
        e[i] = eps
        fd = (ks_jacobians(x + e, u, params, 0.1)[0] - ks_jacobians(x - e, u, params, 0.1)[0]) / (
            2 * eps
        )
        np.testing.assert_allclose(A[:, :, i], fd, atol=1e-6)
    for j in range(2):
        e = np.zeros(2)
        e[j] = eps
        fd = (ks_jacobians(x, u + e, params, 0.1)[0] - ks_jacobians(x, u - e, params, 0.1)[0]) / (
            2 * eps
        )
        np.testing.assert_allclose(B[:, :, j], fd, atol=1e-6)
    # Steady kinematic cornering: yaw rate v tan(delta) cos(beta_k) / L.
    bk = np.arctan(params.lr / params.L * np.tan(x[:, DELTA]))
    np.testing.assert_allclose(
        f[:, PSI], x[:, V] * np.cos(bk) * np.tan(x[:, DELTA]) / params.L, rtol=1e-12
    )


@pytest.mark.parametrize("model", ["st", "ks"])
def test_sparse_assembly_equals_dense_build(course, params, model):
    ctrl = NmpcController(course, params, dataclasses.replace(CFG, horizon=12, model=model))
    x = offset_start(course, params, s_m=30.0, lateral_m=0.4)
    for _ in range(3):  # warm path: shifted plans, duals, non-zero previous input
        ctrl.update(x, params.theta)
        x = x + np.array([0.2, 0.05, 0.01, 0.02, 0.01, 0.0, 0.0])
    lin = ctrl.linearize(x, params.theta, ctrl.memory, ctrl.profile(params.mu))
    P, q, A, lo, hi = ctrl.qp_matrices(lin)
    Pd, qd, Ad, lod, hid = dense_qp(ctrl, lin)
    Pu = P.toarray()
    assert np.allclose(np.tril(Pu, -1), 0.0)
    np.testing.assert_allclose(Pu + np.triu(Pu, 1).T, Pd, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(q, qd, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(A.toarray(), Ad, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lo, lod, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(hi, hid, rtol=1e-12, atol=1e-12)
    # The pattern is fixed: a second linearisation reuses the same CSC structure.
    P2, _, A2, _, _ = ctrl.qp_matrices(
        ctrl.linearize(x * 1.01, params.theta, ctrl.memory, ctrl.profile(0.5))
    )
    np.testing.assert_array_equal(P2.indices, P.indices)
    np.testing.assert_array_equal(A2.indptr, A.indptr)


def test_first_solution_satisfies_the_linearised_dynamics(course, params):
    ctrl = NmpcController(course, params, dataclasses.replace(CFG, horizon=20))
    x = offset_start(course, params, lateral_m=0.5)
    ctrl.update(x, params.theta)
    assert ctrl.last_diagnostics.mode == "qp"
    plan_x, plan_u = ctrl.memory.x_plan, ctrl.memory.u_plan
    np.testing.assert_allclose(plan_x[0], x, atol=1e-3)  # OSQP tolerance
    assert np.all(plan_u[:, 0] <= params.delta_dot_max + 1e-6)
    assert np.all(plan_u[:, 0] >= params.delta_dot_min - 1e-6)
    # The planned first step agrees with the nonlinear model over one step.
    from pcvfe_drake.vehicle.single_track import rk4_step

    nxt = x
    for _ in range(10):
        nxt = rk4_step(nxt, plan_u[0], params, 0.005)
    np.testing.assert_allclose(nxt[:2], plan_x[1, :2], atol=5e-3)


def test_an_update_never_writes_into_the_memory_it_was_given(course, params):
    # Drake's copies of the controller's abstract state share the memory (its __deepcopy__
    # returns it), which is right only while no update, solved or fallback, writes into it.
    ctrl = NmpcController(course, params, dataclasses.replace(CFG, horizon=10))
    x = offset_start(course, params, lateral_m=0.3)
    memory = ctrl.memory
    for _ in range(3):
        _, nxt, _ = ctrl.step(x, params.theta, memory)
        before = copy.deepcopy(dataclasses.asdict(memory))
        ctrl.step(x + 0.01, params.theta, memory)  # solved from the same memory
        ctrl._solver.update_settings(max_iter=1)
        ctrl.step(x, params.theta, memory)  # a fallback from it
        ctrl._solver.update_settings(max_iter=CFG.max_iter)
        after = dataclasses.asdict(memory)
        for name, value in before.items():
            if isinstance(value, np.ndarray):
                assert np.array_equal(after[name], value, equal_nan=True), name
            else:
                assert after[name] == value, name
        assert copy.deepcopy(memory) is memory
        memory = nxt


def test_fallback_shifted_plan_then_braking_never_raises(course, params):
    cfg = dataclasses.replace(CFG, horizon=10, fallback_shift_steps=3)
    ctrl = NmpcController(course, params, cfg)
    x = offset_start(course, params)
    ctrl.update(x, params.theta)
    assert ctrl.last_diagnostics.mode == "qp"
    plan = ctrl.memory.u_plan.copy()
    ctrl._solver.update_settings(max_iter=1)  # force OSQP to stop unsolved
    for j in (1, 2, 3):
        u = ctrl.update(x, params.theta)
        d = ctrl.last_diagnostics
        assert d.mode == "shifted_plan" and "maximum iterations" in d.status
        np.testing.assert_allclose(u, plan[j])
        assert d.fallback_count == j and d.consecutive_fallbacks == j
    u = ctrl.update(x, params.theta)
    assert ctrl.last_diagnostics.mode == "braking"
    assert u[0] == 0.0 and u[1] == pytest.approx(-cfg.brake_fraction * params.mu * params.g)
    # Recovery resets the consecutive counter but keeps the total.
    ctrl._solver.update_settings(max_iter=CFG.max_iter)
    ctrl.update(x, params.theta)
    d = ctrl.last_diagnostics
    assert d.mode == "qp" and d.consecutive_fallbacks == 0 and d.fallback_count == 4


def test_failing_solver_from_the_start_and_bad_inputs(course, params):
    ctrl = NmpcController(course, params, dataclasses.replace(CFG, horizon=10, max_iter=1))
    x = offset_start(course, params)
    u = ctrl.update(x, params.theta)
    assert ctrl.last_diagnostics.mode == "braking" and u[1] < 0
    ok = NmpcController(course, params, dataclasses.replace(CFG, horizon=10))
    bad = x.copy()
    bad[V] = np.nan
    u = ok.update(bad, params.theta)
    assert ok.last_diagnostics.mode == "braking"
    assert ok.last_diagnostics.status == "state not finite" and np.all(np.isfinite(u))
    ok.update(x, [np.nan, 1.0, 1.0])
    assert "nominal" in ok.last_diagnostics.status
    assert ok.last_diagnostics.mu_hat == pytest.approx(params.mu)
    # Stopped (v = 0) braking does not command reversing.
    stopped = x.copy()
    stopped[V] = 0.0
    u, _, diag = ctrl.step(stopped, params.theta, ctrl.memory)
    assert diag.mode == "braking" and u[1] == 0.0


def test_ctrl_c_during_the_osqp_solve_is_raised_not_a_fallback(course, params):
    """OSQP catches SIGINT during a solve and returns the status 'interrupted' (checked by hand:
    osqp 1.1.3 prints "Solver interrupted"); the controller must raise KeyboardInterrupt, not
    brake one step and carry on."""
    from types import SimpleNamespace

    ctrl = NmpcController(course, params, dataclasses.replace(CFG, horizon=10))
    real = ctrl._solver

    class InterruptedSolver:
        def __getattr__(self, name):
            return getattr(real, name)

        def solve(self, raise_error=False):
            res = real.solve(raise_error=raise_error)
            return SimpleNamespace(x=res.x, y=res.y, info=SimpleNamespace(status="interrupted"))

    ctrl._solver = InterruptedSolver()
    with pytest.raises(KeyboardInterrupt):
        ctrl.update(offset_start(course, params), params.theta)
    assert ctrl.memory.fallback_count == 0


def test_wall_clock_limit_triggers_the_fallback(course, params):
    ctrl = NmpcController(course, params, dataclasses.replace(CFG, time_limit_s=1e-9))
    ctrl.update(offset_start(course, params), params.theta)
    d = ctrl.last_diagnostics
    assert d.mode == "braking" and "time limit" in d.status and d.fallback_count == 1


def test_low_friction_belief_slows_the_car_down(course, params):
    ctrl = NmpcController(course, params, CFG)
    x = initial_state(course, params, 5.0, 0.0)  # entering a 12 m S-curve arc
    u = ctrl.update(x, [0.1, params.C_Sf, params.C_Sr])
    assert ctrl.last_diagnostics.v_ref_mps < 3.0
    assert u[1] < -0.3


def test_short_closed_loop_converges_to_the_path(course, params):
    ctrl = NmpcController(course, params, CFG)
    x0 = offset_start(course, params, s_m=150.0, lateral_m=0.8, speed=4.0)
    res = simulate_closed_loop(ctrl, x0, 4.0, mu_at=lambda xy: 0.45)
    assert res.failure == ""
    assert abs(res.lateral_error[0]) == pytest.approx(0.8, abs=1e-3)
    assert np.max(np.abs(res.lateral_error[-100:])) < 0.1
    m = res.metrics(course)
    assert m["fallbacks"] == 0 and m["distance_m"] > 15.0
    assert np.mean(res.x[-50:, V]) == pytest.approx(course.speed, abs=0.3)


def test_kmpc_variant_tracks_with_the_st_truth(course, params):
    cfg = dataclasses.replace(CFG, model="ks")
    ctrl = NmpcController(course, params, cfg)
    x0 = offset_start(course, params, s_m=0.0, lateral_m=0.3)
    res = simulate_closed_loop(ctrl, x0, 3.0, mu_at=lambda xy: 0.6)
    assert res.failure == "" and res.metrics(course)["fallbacks"] == 0
    assert np.sqrt(np.mean(res.lateral_error[100:] ** 2)) < 0.3


def test_config_validation(params):
    with pytest.raises(ValueError, match="model"):
        NmpcConfig(model="bicycle").resolved(params)
    with pytest.raises(ValueError, match="horizon"):
        NmpcConfig(horizon=1).resolved(params)
    cfg = NmpcConfig().resolved(params)
    assert cfg.lateral_scale_m == pytest.approx(0.08 * params.L)
    assert cfg.horizon * cfg.dt_s >= 2.0


def test_starts_from_standstill_within_the_friction_limit(course, params):
    # Linearisation at v = 0 is clamped; without the reference's rise limit the friction
    # polygon, not the cost, caps the launch acceleration.
    ctrl = NmpcController(course, params, dataclasses.replace(CFG, ref_rise_limit=False))
    x0 = initial_state(course, params, 0.0, 100.0)
    res = simulate_closed_loop(ctrl, x0, 2.0, mu_at=lambda xy: 0.45)
    assert res.failure == "" and res.metrics(course)["fallbacks"] == 0
    assert res.x[-1, V] > 3.0
    assert np.max(np.abs(res.lateral_error)) < 0.05
    limit = CFG.friction_margin * 0.45 * params.g
    assert np.max(res.u[:, 1]) <= limit * 1.02
    assert np.max(res.u[:, 1]) > 0.8 * limit  # the constraint, not the cost, limits the launch


@pytest.mark.parametrize("limited", [True, False])
def test_catching_up_before_a_bend_follows_the_profile(course, params, limited):
    # paper_eval's start: 3 m/s, 30 m before the first bend, a 12 m/s cap, mu 0.45. The
    # reference rising from the measured speed at the profile's acceleration keeps the car on
    # the profile's acceleration; with the bare profile it catches up at the friction polygon's
    # limit and enters the bend using ~90 % of the friction (on a tyre whose longitudinal grip
    # also scales with mu, the multi-body car then locks its wheels braking).
    cfg = dataclasses.replace(CFG, max_speed_mps=12.0, ref_rise_limit=limited)
    ctrl = NmpcController(course, params, cfg)
    length = course.s[-1] + course.ds
    res = simulate_closed_loop(
        ctrl, initial_state(course, params, 3.0, length - 30.0), 6.0, mu_at=lambda xy: 0.45
    )
    assert res.failure == "" and res.metrics(course)["fallbacks"] == 0
    n = len(res.u)
    used_g = np.hypot(res.u[:, 1], res.x[:n, V] * res.x[:n, PSI_DOT]) / params.g
    a_profile = cfg.long_fraction * 0.45 * params.g
    if limited:
        assert np.max(res.u[:, 1]) <= 1.05 * a_profile
        assert np.max(used_g) < 0.75 * 0.45
    else:
        assert np.max(res.u[:, 1]) > 1.5 * a_profile
        assert np.max(used_g) > 0.85 * 0.45


def test_multibody_truth_plant_drives_the_closed_loop(course, params):
    from pcvfe_drake.control.closed_loop import MbTruthPlant

    ctrl = NmpcController(course, params, CFG)
    x0 = offset_start(course, params, s_m=20.0, speed=5.0)
    plant = MbTruthPlant(friction_scaling="lateral_peak")
    np.testing.assert_allclose(plant.reset(x0)[:2], x0[:2])
    res = simulate_closed_loop(ctrl, x0, 1.0, mu_at=lambda xy: 0.6, truth=plant)
    assert res.failure == "" and res.metrics(course)["fallbacks"] == 0
    assert res.x[-1, V] > 4.0 and np.max(np.abs(res.lateral_error)) < 0.3


def test_the_closed_loop_ends_on_the_multibody_truths_singularity(course, params, monkeypatch):
    """Braking held past standstill reverses the car out of the multi-body model: the Drake-free
    closed loop ends with that failure named, as the diagram's run loop does."""
    from pcvfe_drake.control.closed_loop import MbTruthPlant

    ctrl = NmpcController(course, params, dataclasses.replace(CFG, horizon=10))
    monkeypatch.setattr(ctrl, "update", lambda x, theta: np.array([0.0, -params.a_max]))
    ctrl.last_diagnostics = None
    x0 = offset_start(course, params, s_m=20.0, speed=0.5)
    res = simulate_closed_loop(ctrl, x0, 2.0, truth=MbTruthPlant(), stop_on_failure=False)
    assert "truth model singular" in res.failure and "reversing" in res.failure
    assert res.t[-1] < 1.0


def test_friction_clip_keeps_the_applied_acceleration_within_the_circle_left(course, params):
    """``friction_clip``: the applied acceleration at most what the friction circle of radius
    friction_margin * mu g leaves after the measured lateral acceleration v psi_dot."""
    mu, g = 0.5, params.g
    radius = CFG.friction_margin * mu * g
    x = np.zeros(7)
    x[V], x[PSI_DOT] = 10.0, 0.6 * radius / 10.0  # a_y = 0.6 R: room 0.8 R
    room = 0.8 * radius
    off = NmpcController(course, params, CFG)
    drive = NmpcController(course, params, dataclasses.replace(CFG, friction_clip="drive"))
    both = NmpcController(course, params, dataclasses.replace(CFG, friction_clip="both"))
    for a in (-4.0, -1.0, 1.0, 4.0):
        assert off.clip_to_friction(a, x, mu) == a
    assert drive.clip_to_friction(4.0, x, mu) == pytest.approx(room)
    assert drive.clip_to_friction(-4.0, x, mu) == -4.0  # braking left to the polygon
    assert drive.clip_to_friction(1.0, x, mu) == 1.0
    assert both.clip_to_friction(-4.0, x, mu) == pytest.approx(-room)
    x[PSI_DOT] = -1.2 * radius / 10.0  # turning beyond the circle: no room either way
    assert both.clip_to_friction(-4.0, x, mu) == 0.0 and drive.clip_to_friction(2.0, x, mu) == 0.0
    with pytest.raises(ValueError, match="friction_clip"):
        NmpcController(course, params, dataclasses.replace(CFG, friction_clip="brake"))
