"""The ST model against CommonRoad (the oracle), finite differences and its own invariants."""

import numpy as np
import pytest
from vehiclemodels.parameters_vehicle1 import parameters_vehicle1
from vehiclemodels.parameters_vehicle2 import parameters_vehicle2
from vehiclemodels.parameters_vehicle3 import parameters_vehicle3
from vehiclemodels.vehicle_dynamics_st import vehicle_dynamics_st

from pcvfe_drake.vehicle import single_track as st
from pcvfe_drake.vehicle.params import VehicleParams, ford_escort

CR_PARAMS = {
    "vehicle1": parameters_vehicle1,
    "vehicle2": parameters_vehicle2,
    "vehicle3": parameters_vehicle3,
}


def random_states(rng, n, v_low=0.5, v_high=40.0):
    x = np.column_stack(
        [
            rng.uniform(-100, 100, n),
            rng.uniform(-100, 100, n),
            rng.uniform(-1.0, 1.0, n),  # beyond the steering limits on purpose
            rng.uniform(v_low, v_high, n),
            rng.uniform(-6, 6, n),
            rng.uniform(-1.5, 1.5, n),
            rng.uniform(-0.4, 0.4, n),
        ]
    )
    u = np.column_stack([rng.uniform(-0.8, 0.8, n), rng.uniform(-14, 14, n)])
    return x, u


def test_package_reference_values():
    """CommonRoad's own unit-test state and derivative (vehicle 2)."""
    params = VehicleParams.from_commonroad(parameters_vehicle2())
    x = [
        2.0233348142065677,
        0.0041907137716636,
        0.0197545248559617,
        15.7216236334290116,
        0.0025857914776859,
        0.0529001056654038,
        0.0033012170610298,
    ]
    u = [0.15, 0.63 * 9.81]
    expected = [
        15.7213512030862397,
        0.0925527979719355,
        0.15,
        5.3536773276413925,
        0.0529001056654038,
        0.6435589397748606,
        0.0313297971641291,
    ]
    np.testing.assert_allclose(st.st_dynamics(x, u, params), expected, rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize("vehicle", sorted(CR_PARAMS))
def test_matches_commonroad_on_random_states(vehicle):
    p = CR_PARAMS[vehicle]()
    params = VehicleParams.from_commonroad(p)
    rng = np.random.default_rng(42)
    x, u = random_states(rng, 3000, v_low=st.V_BLEND_HI)
    ours = st.st_dynamics(x, u, params)
    ref = np.array([vehicle_dynamics_st(x[i], u[i], p) for i in range(len(x))])
    scale = np.maximum(np.abs(ref), 1e-12)
    rel = np.abs(ours - ref) / scale
    # Relative 1e-9, except that entries that are zero up to rounding compare absolutely.
    assert np.all((rel < 1e-9) | (np.abs(ours - ref) < 1e-12)), rel.max()


def test_low_speed_blend_is_smooth_and_finite():
    params = ford_escort()

    def derivative_on_grid(n):
        v = np.linspace(-2.0, 1.0, n)
        x = np.zeros((v.size, 7))
        x[:, st.DELTA] = 0.2
        x[:, st.V] = v
        x[:, st.PSI_DOT] = 0.05
        x[:, st.BETA] = 0.02
        u = np.tile([0.1, 1.0], (v.size, 1))
        return st.st_dynamics(x, u, params)

    coarse = derivative_on_grid(3001)
    fine = derivative_on_grid(30001)
    assert np.all(np.isfinite(fine))
    # Continuity: refining the speed grid 10x shrinks the largest jump about 10x. A hard switch
    # (as CommonRoad's at 0.1 m/s) would keep its jump at every resolution.
    jump_coarse = np.abs(np.diff(coarse, axis=0)).max()
    jump_fine = np.abs(np.diff(fine, axis=0)).max()
    assert jump_fine < 0.15 * jump_coarse, (jump_coarse, jump_fine)


def test_kinematic_branch_uses_correct_slip_rate():
    """Below V_BLEND_LO: beta' is the exact derivative of atan(lr tan(delta) / L)."""
    params = ford_escort()
    delta = 0.4
    steer_rate = 0.3
    x = np.array([0, 0, delta, 0.05, 0.0, 0.0, 0.0])
    f = st.st_dynamics(x, [steer_rate, 0.0], params)
    c = params.lr / params.L
    h = 1e-7
    numeric = (np.arctan(c * np.tan(delta + h)) - np.arctan(c * np.tan(delta - h))) / (2 * h)
    assert f[st.BETA] == pytest.approx(numeric * steer_rate, rel=1e-7)
    # CommonRoad's formula squares tan(delta)^2 lr / L; it differs measurably here.
    wrong = (params.lr * steer_rate) / (
        params.L * np.cos(delta) ** 2 * (1 + (np.tan(delta) ** 2 * params.lr / params.L) ** 2)
    )
    assert abs(f[st.BETA] - wrong) > 1e-4
    # Kinematic yaw rate: v cos(beta_k) tan(delta) / L.
    beta_k = np.arctan(c * np.tan(delta))
    assert f[st.PSI] == pytest.approx(0.05 * np.cos(beta_k) * np.tan(delta) / params.L)


def _away_from_kinks(x, u, params, margin=1e-4):
    """Masks states whose finite-difference stencil would cross a constraint kink."""
    p = params
    v = x[:, st.V]
    pos_limit = np.where(v > p.v_switch, p.a_max * p.v_switch / np.maximum(v, 1e-9), p.a_max)
    ok = np.abs(v - p.v_switch) > margin
    ok &= np.abs(u[:, 1] - pos_limit) > margin
    ok &= np.abs(np.abs(u[:, 1]) - p.a_max) > margin
    ok &= np.abs(u[:, 0] - p.delta_dot_min) > margin
    ok &= np.abs(u[:, 0] - p.delta_dot_max) > margin
    ok &= np.abs(x[:, st.DELTA] - p.delta_min) > margin
    ok &= np.abs(x[:, st.DELTA] - p.delta_max) > margin
    for edge in (st.V_BLEND_LO, st.V_BLEND_HI):
        ok &= np.abs(v - edge) > margin
    return ok


def test_jacobians_match_finite_differences():
    params = ford_escort()
    rng = np.random.default_rng(7)
    x, u = random_states(rng, 4000, v_low=-1.0, v_high=30.0)
    keep = _away_from_kinks(x, u, params)
    x, u = x[keep], u[keep]
    f, A, B, P = st.st_jacobians(x, u, params)
    np.testing.assert_allclose(f, st.st_dynamics(x, u, params))
    eps = 1e-6

    def central(fun, base, j):
        d = np.zeros(base.shape[-1])
        d[j] = eps
        return (fun(base + d) - fun(base - d)) / (2 * eps)

    for j in range(st.NX):
        fd = central(lambda xx: st.st_dynamics(xx, u, params), x, j)
        np.testing.assert_allclose(A[:, :, j], fd, rtol=1e-5, atol=1e-5, err_msg=f"A col {j}")
    for j in range(st.NU):
        fd = central(lambda uu: st.st_dynamics(x, uu, params), u, j)
        np.testing.assert_allclose(B[:, :, j], fd, rtol=1e-5, atol=1e-5, err_msg=f"B col {j}")
    theta = params.theta
    for j in range(st.NTHETA):
        fd = central(lambda th: st.st_dynamics(x, u, params, th), theta, j)
        np.testing.assert_allclose(P[:, :, j], fd, rtol=1e-5, atol=1e-5, err_msg=f"P col {j}")


def test_rk4_step_jacobians_match_finite_differences():
    params = ford_escort()
    rng = np.random.default_rng(3)
    x, u = random_states(rng, 500, v_low=1.0, v_high=25.0)
    keep = _away_from_kinks(x, u, params, margin=1e-2)
    x, u = x[keep], u[keep]
    dt = 0.01
    xn, ad, bd, pd = st.rk4_step(x, u, params, dt, jacobians=True)
    np.testing.assert_allclose(xn, st.rk4_step(x, u, params, dt))
    eps = 1e-6
    for j in range(st.NX):
        d = np.zeros(st.NX)
        d[j] = eps
        fd = (st.rk4_step(x + d, u, params, dt) - st.rk4_step(x - d, u, params, dt)) / (2 * eps)
        np.testing.assert_allclose(ad[:, :, j], fd, rtol=1e-6, atol=1e-7)
    for j in range(st.NU):
        d = np.zeros(st.NU)
        d[j] = eps
        fd = (st.rk4_step(x, u + d, params, dt) - st.rk4_step(x, u - d, params, dt)) / (2 * eps)
        np.testing.assert_allclose(bd[:, :, j], fd, rtol=1e-6, atol=1e-7)
    for j in range(st.NTHETA):
        d = np.zeros(st.NTHETA)
        d[j] = eps
        th = params.theta
        fd = (st.rk4_step(x, u, params, dt, th + d) - st.rk4_step(x, u, params, dt, th - d)) / (
            2 * eps
        )
        np.testing.assert_allclose(pd[:, :, j], fd, rtol=1e-6, atol=1e-7)


def test_rollout_sensitivities_match_finite_differences():
    params = ford_escort()
    rng = np.random.default_rng(11)
    nb, horizon, dt = 6, 25, 0.01
    x0 = np.zeros((nb, 7))
    x0[:, st.V] = rng.uniform(4, 15, nb)
    x0[:, st.DELTA] = rng.uniform(-0.1, 0.1, nb)
    U = np.stack(
        [rng.uniform(-0.3, 0.3, (nb, horizon)), rng.uniform(-2, 2, (nb, horizon))], axis=-1
    )
    theta = np.array([0.6, 20.0, 22.0])
    X, S = st.rollout(x0, U, params, dt, theta, sensitivities=True)
    assert X.shape == (nb, horizon + 1, 7) and S.shape == (nb, horizon + 1, 7, 3)
    np.testing.assert_array_equal(X[:, 0], x0)
    eps = 1e-6
    for j in range(3):
        d = np.zeros(3)
        d[j] = eps
        fd = (
            st.rollout(x0, U, params, dt, theta + d) - st.rollout(x0, U, params, dt, theta - d)
        ) / (2 * eps)
        np.testing.assert_allclose(S[..., j], fd, rtol=1e-5, atol=1e-8)


def test_identifiability_mu_times_stiffness():
    """(mu, C_Sf, C_Sr) and (mu/2, 2 C_Sf, 2 C_Sr) give identical trajectories (FACTS.md)."""
    params = ford_escort()
    x0 = np.array([0, 0, 0.05, 10.0, 0, 0.1, 0.01])
    U = np.column_stack([0.2 * np.sin(np.linspace(0, 6, 200)), np.full(200, 0.5)])
    a = st.rollout(x0, U, params, 0.01, theta=[1.0, 20.0, 25.0])
    b = st.rollout(x0, U, params, 0.01, theta=[0.5, 40.0, 50.0])
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10)
    c = st.rollout(x0, U, params, 0.01, theta=[0.5, 20.0, 25.0])
    assert np.abs(a - c).max() > 0.1


def test_input_constraints():
    params = ford_escort()
    x = np.zeros((4, 7))
    x[:, st.V] = [10.0, 2.0, 10.0, 10.0]
    x[:, st.DELTA] = [0.0, 0.0, params.delta_max, 0.0]
    u = np.array([[5.0, 50.0], [-5.0, -50.0], [0.1, 0.0], [0.1, 2.0]])
    u_eff, *_ = st.constrain_inputs(x, u, params)
    assert u_eff[0, 0] == params.delta_dot_max
    assert u_eff[0, 1] == pytest.approx(params.a_max * params.v_switch / 10.0)
    assert u_eff[1, 0] == params.delta_dot_min
    assert u_eff[1, 1] == -params.a_max
    assert u_eff[2, 0] == 0.0  # steering into the angle limit is stopped
    np.testing.assert_array_equal(u_eff[3], [0.1, 2.0])


def test_rejects_non_finite_and_bad_shapes():
    params = ford_escort()
    x = np.zeros(7)
    x[st.V] = 5.0
    bad = x.copy()
    bad[st.BETA] = np.nan
    with pytest.raises(ValueError, match="non-finite state"):
        st.st_dynamics(bad, [0, 0], params)
    with pytest.raises(ValueError, match="non-finite input"):
        st.st_dynamics(x, [np.inf, 0], params)
    with pytest.raises(ValueError, match="state must have 7"):
        st.st_dynamics(np.zeros(6), [0, 0], params)


def test_wrap_angle():
    a = np.array([0.0, np.pi, -np.pi, 3 * np.pi, 2 * np.pi + 0.1, -0.1])
    w = st.wrap_angle(a)
    assert np.all(w <= np.pi) and np.all(w > -np.pi)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)


def test_single_state_path_equals_batch():
    """One state goes through a scalar fast path (the plant's per-step call); same numbers."""
    params = ford_escort()
    rng = np.random.default_rng(5)
    x, u = random_states(rng, 300, v_low=-1.0, v_high=45.0)
    batch = st.st_dynamics(x, u, params)
    single = np.array([st.st_dynamics(x[i], u[i], params) for i in range(len(x))])
    np.testing.assert_allclose(single, batch, rtol=1e-12, atol=1e-12)
    assert batch.shape == (300, 7)


@pytest.mark.parametrize("vehicle", ["ford_escort", "bmw_320i", "vw_vanagon"])
def test_compiled_jacobians_are_the_numpy_codes_to_the_last_bit(vehicle):
    from pcvfe_drake.vehicle import single_track_kernel
    from pcvfe_drake.vehicle.params import load_vehicle

    if single_track_kernel.dynamic_rows is None:
        pytest.skip("numba is not installed: st_jacobians runs the numpy code only")
    p = load_vehicle(vehicle)
    rng = np.random.default_rng(11)
    for trial in range(60):
        n = int(rng.integers(1, 80))
        x = np.zeros((n, st.NX))
        x[:, :2] = 50 * rng.standard_normal((n, 2))
        x[:, st.DELTA] = rng.uniform(1.1 * p.delta_min, 1.1 * p.delta_max, n)
        x[:, st.V] = st.V_BLEND_HI + 25 * rng.random(n)
        x[:, st.PSI] = 3 * rng.standard_normal(n)
        x[:, st.PSI_DOT] = 0.5 * rng.standard_normal(n)
        x[:, st.BETA] = 0.1 * rng.standard_normal(n)
        x[0, st.V] = st.V_BLEND_HI  # the range's edge: the blend weight's own rounding
        x[-1, st.DELTA], x[-1, st.V] = p.delta_max, max(p.v_max, st.V_BLEND_HI)  # the stops
        u = 1.2 * rng.standard_normal((n, st.NU)) * [p.delta_dot_max, p.a_max]
        theta = (
            p.theta * (0.5 + rng.random(3))
            if trial % 2
            else np.column_stack(
                [
                    rng.uniform(0.1, 1.2, n),
                    p.C_Sf * (0.5 + rng.random(n)),
                    p.C_Sr * (0.5 + rng.random(n)),
                ]
            )
        )
        compiled = st.st_jacobians(x, u, p, theta)
        reference = st._in_blocks(*st._as_batch(x, u, theta, p)[:3], p, True)
        for got, expected in zip(compiled, reference, strict=True):
            assert got.shape == expected.shape
            assert np.array_equal(got.view(np.int64), expected.view(np.int64))


def test_compiled_jacobians_match_finite_differences():
    params = ford_escort()
    rng = np.random.default_rng(8)
    x, u = random_states(rng, 2000, v_low=st.V_BLEND_HI + 0.1, v_high=30.0)
    keep = _away_from_kinks(x, u, params)
    x, u = x[keep], u[keep]
    f, A, B, _ = st.st_jacobians(x, u, params)
    np.testing.assert_allclose(f, st.st_dynamics(x, u, params))
    eps = 1e-6
    for j in range(st.NX):
        d = np.zeros(st.NX)
        d[j] = eps
        fd = (st.st_dynamics(x + d, u, params) - st.st_dynamics(x - d, u, params)) / (2 * eps)
        np.testing.assert_allclose(A[:, :, j], fd, rtol=1e-5, atol=1e-5, err_msg=f"A col {j}")
    for j in range(st.NU):
        d = np.zeros(st.NU)
        d[j] = eps
        fd = (st.st_dynamics(x, u + d, params) - st.st_dynamics(x, u - d, params)) / (2 * eps)
        np.testing.assert_allclose(B[:, :, j], fd, rtol=1e-5, atol=1e-5, err_msg=f"B col {j}")
