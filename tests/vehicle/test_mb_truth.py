"""Tests of the multi-body truth model: friction mapping, state conversion, integration."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import vehiclemodels.utils.tire_model as tire_model
from vehiclemodels.init_mb import init_mb
from vehiclemodels.parameters_vehicle1 import parameters_vehicle1
from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb

from pcvfe_drake.vehicle.mb_truth import (
    NX_MB,
    MbSingularity,
    MbTruth,
    singularity_detail,
    st_state,
    wheel_ground_speeds,
)
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import rollout

FZ_N = 3000.0


@pytest.fixture(scope="module")
def mb() -> MbTruth:
    return MbTruth("ford_escort")


def lateral_force(tire, alpha: float) -> float:
    """Pure-slip lateral force minus its offset at zero slip (camber 0)."""
    return (
        tire_model.formula_lateral(alpha, 0.0, FZ_N, tire)[0]
        - tire_model.formula_lateral(0.0, 0.0, FZ_N, tire)[0]
    )


@pytest.mark.parametrize("mu", [0.3, 0.45, 0.8])
def test_friction_mapping_matches_single_track_parametrisation(mb, mu):
    params = ford_escort()
    tire = mb.parameters_for_mu(mu).tire
    assert tire.p_dy1 == pytest.approx(mu)
    assert tire.p_dx1 == pytest.approx(1.1739 * mu / 1.0489)
    # Small slip: F_y = -mu C_S F_z alpha, the ST model's tire with the same mu.
    alpha = 1e-4
    assert lateral_force(tire, alpha) / alpha == pytest.approx(-mu * params.C_Sf * FZ_N, rel=1e-5)
    # Peak lateral force mu F_z.
    peak = max(abs(lateral_force(tire, a)) for a in np.linspace(0.0, 0.6, 1500))
    assert peak == pytest.approx(mu * FZ_N, rel=1e-4)


def test_peak_only_scaling_keeps_stiffness(mb):
    peak_only = MbTruth("ford_escort", friction_scaling="peak")
    tire = peak_only.parameters_for_mu(0.3).tire
    nominal = parameters_vehicle1().tire
    assert tire.p_dy1 == pytest.approx(0.3)
    assert tire.p_ky1 == nominal.p_ky1 and tire.p_kx1 == nominal.p_kx1
    stiffness = lateral_force(tire, 1e-4) / 1e-4
    assert stiffness == pytest.approx(nominal.p_ky1 * FZ_N, rel=1e-4)  # unchanged by mu
    # The cache returns one object per mu and the base set is left alone.
    assert mb.parameters_for_mu(0.3) is mb.parameters_for_mu(0.3)
    assert mb.base_parameters.tire.p_dy1 == nominal.p_dy1


def test_derivatives_equal_the_package_with_scaled_tires(mb):
    rng = np.random.default_rng(3)
    reference = parameters_vehicle1()
    for _ in range(10):
        x_st = [*rng.uniform(-50, 50, 2), rng.uniform(-0.3, 0.3), rng.uniform(1, 30)]
        x_st += [rng.uniform(-3, 3), rng.uniform(-0.5, 0.5), rng.uniform(-0.1, 0.1)]
        x = np.array(init_mb(x_st, mb.base_parameters)) + rng.normal(0, 1e-3, NX_MB)
        u = rng.uniform([-0.4, -5.0], [0.4, 5.0])
        mu = rng.uniform(0.2, 1.2)
        p = copy.deepcopy(reference)
        s = mu / p.tire.p_dy1
        for name in ("p_dy1", "p_dx1", "p_ky1", "p_kx1"):
            setattr(p.tire, name, getattr(p.tire, name) * s)
        expected = vehicle_dynamics_mb(x.tolist(), u.tolist(), p)
        np.testing.assert_allclose(mb.derivatives(x, u, mu), expected, rtol=1e-12, atol=1e-12)


def test_st_state_of_one_state_has_the_bits_of_the_batch():
    # One state takes a shorter path than a batch (the plant converts one at every sensor
    # sample); both must give the same bits, also at the kinematic threshold, reversing, at
    # rest and on non-finite speeds.
    rng = np.random.default_rng(5)
    x = rng.normal(size=(4000, 29)) * rng.choice([1e-3, 0.05, 1.0, 30.0], size=(4000, 1))
    x[::7, 3], x[::11, 3], x[::13, 3] = 0.1, -0.1, np.nan
    x[::17, 10], x[::19, 3], x[::23, 3] = np.inf, -0.0, 0.09999999999
    batch = st_state(x)
    one = np.array([st_state(row) for row in x])
    assert np.array_equal(batch.view(np.uint64), one.view(np.uint64))
    assert one.dtype == np.float64 and st_state(x[0]).shape == (7,)


def test_st_state_round_trip_and_conventions(mb):
    x_st = np.array([3.0, -4.0, 0.1, 12.0, 0.7, 0.2, -0.05])
    np.testing.assert_allclose(st_state(mb.initial_state(x_st)), x_st, atol=1e-12)
    x = mb.initial_state(x_st)
    x[3], x[10] = -2.0, 0.1  # reversing: signed speed
    assert st_state(x)[3] == pytest.approx(-np.hypot(2.0, 0.1))
    x[3], x[10] = 0.05, 0.02  # below 0.1 m/s: beta = 0 as in the package
    assert st_state(x)[6] == 0.0
    batch = st_state(np.stack([mb.initial_state(x_st)] * 3))
    assert batch.shape == (3, 7)


def test_gentle_driving_matches_the_single_track_model(mb):
    """With the ST mapping, MB and ST agree in the linear tire range; friction matters."""
    params = ford_escort()
    dt, horizon = 0.05, 40
    t = np.arange(horizon) * dt
    inputs = np.stack([0.03 * np.sin(1.5 * t), np.zeros(horizon)], axis=1)
    x0 = np.array([0.0, 0.0, 0.0, 15.0, 0.0, 0.0, 0.0])
    x_mb, _ = mb.simulate(x0, inputs, dt, 0.6)
    x_st = rollout(x0, inputs, params, dt, theta=[0.6, params.C_Sf, params.C_Sr])
    assert np.abs(x_mb[:, :2] - x_st[:, :2]).max() < 0.2  # m, over 2 s and 30 m
    assert np.abs(x_mb[:, 5] - x_st[:, 5]).max() < 0.04  # rad/s, of a 0.24 rad/s peak
    x_low, _ = mb.simulate(x0, inputs, dt, 0.3)
    assert np.abs(x_low[:, 6]).max() > 3.0 * np.abs(x_mb[:, 6]).max()  # slip grows on low mu


def test_lsoda_and_rk4_agree_at_speed(mb):
    x = mb.initial_state([0.0, 0.0, 0.05, 10.0, 0.0, 0.0, 0.0])
    u = np.array([0.1, 1.0])
    a = mb.integrate(x, u, 0.8, 0.5, method="lsoda", rtol=1e-8, atol=1e-8)
    b = mb.integrate(x, u, 0.8, 0.5, method="rk4", rk4_step_s=1e-3)
    np.testing.assert_allclose(st_state(a), st_state(b), atol=1e-5)


def test_from_rest_with_lsoda(mb):
    x = mb.initial_state(np.zeros(7))
    x1 = mb.integrate(x, np.array([0.0, 2.0]), 0.6, 1.0)
    v = st_state(x1)[3]
    # The reference: 0.1 ms RK4 gives 2.006 m/s. Before wheel speeds were evaluated at >= 0, a
    # rear wheel pushed below 0 stayed locked and the car crawled to 0.37 m/s.
    assert 1.9 < v < 2.1
    assert np.all(x1[23:27] > 0.0)


# A state of the Ford on peak_and_stiffness at mu 0.3147 (the calibration programme's check
# drive, accelerating out of a circle at 7.7 m/s) where the lateral slip crosses zero.
CHATTER_STATE = [
    48.43990461715, -6.816982207423, -0.008855283525, 7.673319872162, 12.32617470644,
    -0.033954044815, 0.003888077152, -0.000857231911, 0.000611553142, 7.9385374e-05,
    0.001305118444, 0.015662437284, -0.000120707031, 0.000609374776, 0.001359092442,
    -0.027063486654, 0.019078733694, -2.2954837e-05, 0.000407299309, -0.000929494389,
    0.05283510646, 0.012607767634, 2.363155e-06, 22.610579548448, 22.735529014462,
    22.220076103612, 22.362943951708, 0.003196721291, 0.002884565928,
]  # fmt: skip


def test_a_chattering_lsoda_interval_is_taken_in_rk4_substeps(monkeypatch):
    """LSODA spent over a million evaluations on this 0.05 s interval; it is stopped at
    ``LSODA_CHATTER_FACTOR`` times RK4's evaluations and the interval taken in RK4 substeps."""
    from pcvfe_drake.vehicle import mb_truth

    soft = MbTruth("ford_escort", friction_scaling="peak_and_stiffness")
    x, u = np.array(CHATTER_STATE), [0.009875086809282417, 0.6174414]
    calls = [0]
    rhs = MbTruth.rhs

    def counted(*args):
        calls[0] += 1
        return rhs(*args)

    monkeypatch.setattr(MbTruth, "rhs", staticmethod(counted))
    a = soft.integrate(x, u, 0.3147, 0.05)
    assert calls[0] <= mb_truth.LSODA_CHATTER_FACTOR * 4 * 50 + 4 * 50 + 2
    np.testing.assert_array_equal(a, soft.integrate(x, u, 0.3147, 0.05, method="rk4"))
    # an interval that does not chatter is LSODA's own
    calls[0] = 0
    calm = soft.initial_state([0.0, 0.0, 0.0, 8.0, 0.0, 0.0, 0.0])
    soft.integrate(calm, [0.0, 0.0], 0.3147, 0.05)
    assert calls[0] < 1000


def test_bad_input_is_named(mb):
    x = mb.initial_state([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"input \[steer_rate, accel\]"):
        mb.derivatives(x, [np.nan, 0.0], 0.5)
    bad = x.copy()
    bad[4] = np.inf
    with pytest.raises(ValueError, match="MB state is not finite"):
        mb.integrate(bad, [0.0, 0.0], 0.5, 0.1)
    with pytest.raises(ValueError, match="mu=-0.1"):
        mb.parameters_for_mu(-0.1)
    with pytest.raises(ValueError, match="no CommonRoad multi-body parameters"):
        MbTruth("roboracer")
    with pytest.raises(ValueError, match="friction_scaling"):
        MbTruth(friction_scaling="linear")
    with pytest.raises(ValueError, match="initial single-track state"):
        mb.initial_state([0.0, 1.0])
    with pytest.raises(ValueError, match="method"):
        mb.integrate(x, [0.0, 0.0], 0.5, 0.1, method="euler")


def test_a_wheel_at_zero_ground_speed_is_the_named_singularity_not_a_zero_division(mb):
    """The package divides by each wheel's ground speed above 0.1 m/s; where one is <= 0 (a
    reversing or spun car) the model ends, and MbTruth says so with the wheels' numbers."""
    x = mb.initial_state([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    p = mb.parameters_for_mu(1.0)
    assert singularity_detail(x, p) == ""
    spun = x.copy()
    spun[5] = 2.5 * 5.0 / p.T_r  # yaw rate: the inner rear wheel moves backwards over ground
    u_w = wheel_ground_speeds(spun, p)
    assert u_w[2] > 0 and u_w[3] < 0
    with pytest.raises(MbSingularity, match="rear right") as caught:
        mb.derivatives(spun, [0.0, 0.0], 1.0)
    assert isinstance(caught.value, ArithmeticError) and "spun" in str(caught.value)
    np.testing.assert_allclose(caught.value.state[:2], spun[:2])
    reversing = mb.initial_state([0.0, 0.0, 0.0, -0.5, 0.0, 0.0, 0.0])
    with pytest.raises(MbSingularity, match="reversing"):
        mb.derivatives(reversing, [0.0, 0.0], 1.0)
    # In the package's kinematic regime (|v_x| < 0.1 m/s) nothing is divided: no singularity.
    creeping = mb.initial_state([0.0, 0.0, 0.0, -0.05, 0.0, 0.0, 0.0])
    assert singularity_detail(creeping, p) == ""
    assert np.all(np.isfinite(mb.derivatives(creeping, [0.0, 0.0], 1.0)))


def test_full_braking_from_a_crawl_ends_in_the_singularity(mb):
    """Braking held past standstill reverses the car (the input is an acceleration), and the
    integration stops with MbSingularity within a fraction of a second."""
    x = mb.initial_state([0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    with pytest.raises(MbSingularity, match="reversing"):
        for _ in range(50):  # 0.5 s
            x = mb.integrate(x, [0.0, -5.0], 1.0, 0.01, method="rk4")
