"""The compiled multi-body derivative against the package it transcribes: equal bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from vehiclemodels.init_mb import init_mb
from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb

from pcvfe_drake.vehicle import mb_kernel
from pcvfe_drake.vehicle.mb_kernel import (
    MB_PARAMETER_FIELDS,
    REGULAR,
    SINGULAR,
    WHEEL_AT_REST_OVER_GROUND,
    ZERO_TIRE_LOAD,
    mb_derivative,
    mb_parameter_vector,
)
from pcvfe_drake.vehicle.mb_truth import (
    FRICTION_SCALINGS,
    MB_VEHICLES,
    NX_MB,
    MbSingularity,
    MbTruth,
    singularity_detail,
)

SPREAD = np.array(
    [0, 0, 0, 0, 0, 0.2, 0.05, 0.2, 0.02, 0.2, 0.5, 0.01, 0.05, 0.02, 0.2]
    + [0.5, 0.01, 0.05, 0.02, 0.2, 0.5, 0.01, 0.05, 5, 5, 5, 5, 0.001, 0.001]
)
"""Standard deviations of the perturbations added to a state at rest in its suspension
(``init_mb``): yaw rate, roll, pitch, heave and the unsprung masses' motion, wheel spin
[rad/s], the compliant joints."""


def reference(x, u, p) -> np.ndarray | None:
    """The package's derivative after MbTruth's clamp of the wheel speeds at 0 (None where it
    divides by zero)."""
    xl = np.asarray(x, dtype=float).tolist()
    for i in range(23, 27):
        if xl[i] < 0.0:
            xl[i] = 0.0
    try:
        return np.array(vehicle_dynamics_mb(xl, list(u), p), dtype=float)
    except ZeroDivisionError:
        return None


def driving_states(rng, p, n: int, v_range=(0.5, 30.0)) -> np.ndarray:
    """``n`` MB states around driving: ``init_mb`` at a random speed, steering, yaw rate and
    slip angle, every other state perturbed (``SPREAD``); some wheel speeds end below 0."""
    rows = []
    for _ in range(n):
        st = [
            rng.uniform(-50, 50),
            rng.uniform(-50, 50),
            rng.uniform(-0.5, 0.5),
            rng.uniform(*v_range),
            rng.uniform(-math.pi, math.pi),
            0.4 * rng.normal(),
            0.1 * rng.normal(),
        ]
        rows.append(np.array(init_mb(st, p)) + SPREAD * rng.normal(size=NX_MB))
    return np.array(rows)


def assert_bit_identical(states, inputs, p, pv) -> int:
    """Kernel and package agree bit for bit on every row, and the kernel signals exactly where
    the package divides by zero; returns how many rows were singular."""
    out = np.empty(NX_MB)
    singular = 0
    for x, u in zip(states, inputs, strict=True):
        ref = reference(x, u, p)
        code = mb_derivative(np.ascontiguousarray(x), float(u[0]), float(u[1]), pv, out)
        if ref is None:
            singular += 1
            assert code != REGULAR, f"package divides by zero, kernel does not: {x.tolist()}"
            continue
        assert code == REGULAR, f"kernel singular ({SINGULAR.get(code)}): {x.tolist()}"
        differ = np.flatnonzero(ref.view(np.uint64) != out.view(np.uint64))
        assert differ.size == 0, (
            f"entries {differ.tolist()} differ by {(out - ref)[differ].tolist()} at state "
            f"{x.tolist()}, input {list(u)}"
        )
    return singular


@pytest.mark.parametrize("vehicle", sorted(MB_VEHICLES))
@pytest.mark.parametrize("scaling", FRICTION_SCALINGS)
def test_random_driving_states_are_bit_identical(vehicle, scaling):
    rng = np.random.default_rng(sorted(MB_VEHICLES).index(vehicle) * 10 + len(scaling))
    truth = MbTruth(vehicle, scaling)
    for mu in (0.25, 0.6, 1.1):
        p = truth.parameters_for_mu(mu)
        pv = truth.parameter_vector_for_mu(mu)
        states = driving_states(rng, p, 100)
        inputs = np.column_stack([0.3 * rng.normal(size=100), 6.0 * rng.normal(size=100)])
        assert_bit_identical(states, inputs, p, pv)


@pytest.mark.parametrize("vehicle", sorted(MB_VEHICLES))
def test_the_kinematic_regime_below_0_1_mps_is_bit_identical(vehicle):
    """|v_x| < 0.1 m/s: the package's kinematic single-track equations (no slip, no division),
    at any wheel speed, also slightly backwards."""
    rng = np.random.default_rng(7)
    truth = MbTruth(vehicle)
    p, pv = truth.parameters_for_mu(0.8), truth.parameter_vector_for_mu(0.8)
    states = driving_states(rng, p, 300, v_range=(-0.099, 0.099))
    states[:, 3] = rng.uniform(-0.0999, 0.0999, size=300)
    states[::7, 3] = 0.0
    inputs = np.column_stack([0.5 * rng.normal(size=300), 8.0 * rng.normal(size=300)])
    assert assert_bit_identical(states, inputs, p, pv) == 0


@pytest.mark.parametrize("vehicle", sorted(MB_VEHICLES))
def test_inputs_at_and_beyond_their_constraints_are_bit_identical(vehicle):
    """Steering at its angle limits with the rate pushing on, rates and accelerations past
    their limits, the power limit above v_switch, the top speed."""
    rng = np.random.default_rng(11)
    truth = MbTruth(vehicle)
    p, pv = truth.parameters_for_mu(0.9), truth.parameter_vector_for_mu(0.9)
    s, lon = p.steering, p.longitudinal
    states = driving_states(rng, p, 240, v_range=(1.0, lon.v_max + 5.0))
    states[0::4, 2] = s.max  # at the angle limit ...
    states[1::4, 2] = s.min
    states[2::4, 2] = rng.choice([s.min - 0.01, s.max + 0.01], size=60)  # ... and past it
    states[::5, 3] = lon.v_max  # the top speed
    states[1::5, 3] = lon.v_switch  # where the power limit starts
    rates = rng.choice([s.v_min, s.v_max, 0.0, -0.0, 2 * s.v_min, 2 * s.v_max], size=240)
    accels = rng.choice(
        [lon.a_max, -lon.a_max, 2 * lon.a_max, -2 * lon.a_max, 0.0, -0.0, 3.0], size=240
    )
    inputs = np.column_stack([rates, accels])
    assert_bit_identical(states, inputs, p, pv)
    kinematic = states.copy()
    kinematic[:, 3] = 0.05  # the kinematic equations apply the constraints a second time
    assert_bit_identical(kinematic, inputs, p, pv)


@pytest.mark.parametrize("vehicle", sorted(MB_VEHICLES))
def test_large_slip_is_bit_identical(vehicle):
    """Locked and spinning wheels, large slip angles, lifted and compressed suspension."""
    rng = np.random.default_rng(13)
    truth = MbTruth(vehicle)
    p, pv = truth.parameters_for_mu(0.5), truth.parameter_vector_for_mu(0.5)
    n = 300
    states = driving_states(rng, p, n, v_range=(2.0, 25.0))
    rolling = states[:, 3:4] / p.R_w
    states[:, 23:27] = rolling * rng.choice([0.0, 0.3, 1.0, 1.8, 3.0], size=(n, 4))
    states[:, 10] = states[:, 3] * rng.uniform(-0.8, 0.8, size=n)  # slip angles up to ~40 deg
    states[:, 5] = rng.uniform(-1.0, 1.0, size=n)
    states[:, 16] += rng.uniform(-0.02, 0.02, size=n)  # tire deflection, front
    states[:, 21] += rng.uniform(-0.02, 0.02, size=n)  # and rear
    states[:, 6] = rng.uniform(-0.1, 0.1, size=n)  # roll (camber)
    inputs = np.column_stack([rng.normal(size=n), 10.0 * rng.normal(size=n)])
    singular = assert_bit_identical(states, inputs, p, pv)
    assert singular < n // 2  # most of these states are inside the model


def test_where_the_package_divides_by_zero_rhs_raises_the_same_singularity():
    truth = MbTruth("ford_escort")
    p, pv = truth.parameters_for_mu(1.0), truth.parameter_vector_for_mu(1.0)
    x = truth.initial_state([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    spun = x.copy()
    spun[5] = 2.5 * 5.0 / p.T_r  # the inner rear wheel moves backwards over the ground
    spun[24] = -3.0  # a negative wheel speed: evaluated (and reported) at 0
    assert reference(spun, [0.0, 0.0], p) is None
    with pytest.raises(MbSingularity) as caught:
        MbTruth.rhs(spun, [0.0, 0.0], pv)
    clamped = spun.copy()
    clamped[24] = 0.0
    assert caught.value.detail == singularity_detail(clamped, p)
    assert "rear right" in caught.value.detail
    np.testing.assert_array_equal(caught.value.state, clamped)
    assert spun[24] == -3.0  # the caller's state is not changed
    # a tire without load: the package divides by zero in its stiffness factor, also in the
    # kinematic regime, where no wheel speed is divided by
    for v in (5.0, 0.05):
        lifted = truth.initial_state([0.0, 0.0, 0.0, v, 0.0, 0.0, 0.0])
        lifted[13], lifted[16] = 0.0, 0.0  # front: no roll, no tire deflection
        assert reference(lifted, [0.0, 0.0], p) is None
        out = np.empty(NX_MB)
        assert mb_derivative(lifted, 0.0, 0.0, pv, out) == ZERO_TIRE_LOAD
        assert np.all(np.isnan(out))
        with pytest.raises(MbSingularity, match="vertical load is 0"):
            MbTruth.rhs(lifted, [0.0, 0.0], pv)


def test_rhs_takes_lists_arrays_and_parameter_sets_alike():
    truth = MbTruth("bmw_320i", "peak")
    p, pv = truth.parameters_for_mu(0.7), truth.parameter_vector_for_mu(0.7)
    x = truth.initial_state([1.0, 2.0, 0.05, 12.0, 0.3, 0.2, 0.02])
    x[23] = -1.0
    ref = reference(x, [0.1, 1.0], p)
    strided = np.repeat(x, 2)[::2]  # not contiguous: copied for the kernel
    read_only = x.copy()
    read_only.flags.writeable = False
    for state in (x, x.tolist(), strided, read_only):
        np.testing.assert_array_equal(MbTruth.rhs(state, [0.1, 1.0], pv), ref)
    np.testing.assert_array_equal(MbTruth.rhs(x, np.array([0.1, 1.0]), p), ref)
    np.testing.assert_array_equal(truth.derivatives(x, [0.1, 1.0], 0.7), ref)
    assert x[23] == -1.0
    assert truth.parameter_vector_for_mu(0.7) is pv  # cached
    with pytest.raises(ValueError, match="state of shape"):
        MbTruth.rhs(x[:28], [0.0, 0.0], pv)


def test_rk4_integration_is_the_package_s_rk4():
    """MbTruth.integrate's RK4 with the kernel equals the same RK4 on the package's derivative
    (50 substeps)."""
    truth = MbTruth("vw_vanagon", "lateral_peak")
    p = truth.parameters_for_mu(0.4)
    x0 = truth.initial_state([0.0, 0.0, 0.1, 8.0, 0.0, 0.3, 0.01])
    u = [0.2, 1.5]
    got = truth.integrate(x0, u, 0.4, 0.05, method="rk4", rk4_step_s=1e-3)
    xn, h = x0.copy(), 0.05 / 50
    for _ in range(50):
        k1 = reference(xn, u, p)
        k2 = reference(xn + 0.5 * h * k1, u, p)
        k3 = reference(xn + 0.5 * h * k2, u, p)
        k4 = reference(xn + h * k3, u, p)
        xn = xn + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        np.maximum(xn[23:27], 0.0, out=xn[23:27])
    np.testing.assert_array_equal(got, xn)


def test_the_compiled_error_controlled_steps_meet_the_fine_reference_and_report_failures():
    """``mb_advance`` (``method="rk23"``): 0.5 s of a braking bend within its tolerance of
    0.1 ms RK4 substeps, in one call; a stage where the package divides by zero and a step
    below the least both come back as codes, and ``MbTruth.advance`` raises them."""
    truth = MbTruth("bmw_320i", "peak_and_stiffness")
    pv = truth.parameter_vector_for_mu(0.5)
    x0 = truth.initial_state([0.0, 0.0, 0.08, 9.0, 0.0, 0.4, 0.02])
    u = [-0.1, -3.0]
    fine = truth.integrate(x0, u, 0.5, 0.5, method="rk4", rk4_step_s=1e-4)
    out = np.empty(NX_MB)
    code, step, evals = mb_kernel.mb_advance(x0, -0.1, -3.0, pv, 0.5, 0.5, 1e-5, 1e-5, 1e-8, out)
    assert code == REGULAR and 0 < step < 0.5 and evals % 3 == 1
    np.testing.assert_allclose(out, fine, atol=2e-4)
    assert np.hypot(*(out[:2] - fine[:2])) < 1e-4
    x_before = x0.copy()
    np.testing.assert_array_equal(truth.integrate(x0, u, 0.5, 0.5, method="rk23"), out)
    np.testing.assert_array_equal(x0, x_before)  # not changed
    # a step below the least: error control cannot meet 1e-12 with steps of 0.1 s or more
    code, _, _ = mb_kernel.mb_advance(x0, -0.1, -3.0, pv, 0.5, 0.5, 1e-12, 1e-12, 0.1, out)
    assert code == mb_kernel.STEP_TOO_SMALL
    # reversing: the first derivative divides by zero
    reversing = truth.initial_state([0.0, 0.0, 0.0, -0.5, 0.0, 0.0, 0.0])
    code, _, evals = mb_kernel.mb_advance(
        reversing, 0.0, 0.0, pv, 0.01, 0.01, 1e-5, 1e-5, 1e-8, out
    )
    assert code == WHEEL_AT_REST_OVER_GROUND and evals == 1
    with pytest.raises(MbSingularity, match="reversing"):
        truth.advance(reversing, [0.0, 0.0], pv, 0.01, 0.01)


def test_the_parameter_vector_names_each_field_and_refuses_bad_ones():
    p = MbTruth("ford_escort").parameters_for_mu(0.5)
    pv = mb_parameter_vector(p)
    assert pv.shape == (len(MB_PARAMETER_FIELDS),) and pv.dtype == np.float64
    assert pv[mb_kernel.P_DY1] == p.tire.p_dy1 and pv[mb_kernel.R_VY6] == p.tire.r_vy6
    assert pv[mb_kernel.STEER_RATE_MAX] == p.steering.v_max
    assert pv[mb_kernel.A_MAX] == p.longitudinal.a_max and pv[mb_kernel.I_Y_W] == p.I_y_w
    p.tire.r_vy6 = None
    with pytest.raises(ValueError, match="tire.r_vy6 = None is not a number"):
        mb_parameter_vector(p)
    p.tire.r_vy6 = math.nan
    with pytest.raises(ValueError, match="tire.r_vy6 = nan is not finite"):
        mb_parameter_vector(p)
    p.tire.r_vy6 = "soft"
    with pytest.raises(ValueError, match="tire.r_vy6 = 'soft' is not a number"):
        mb_parameter_vector(p)
    p.tire = object()
    with pytest.raises(ValueError, match="has no 'tire.p_cx1'"):
        mb_parameter_vector(p)
