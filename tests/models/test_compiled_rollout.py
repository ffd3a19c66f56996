"""The compiled RK4 rollout (``models/compiled_rollout.py``) gives the numpy rollout's numbers,
and models it does not know are rolled out by numpy."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest

from pcvfe_drake.models.compiled_rollout import COMPILED_EFFECTS, compiled_effect_plan
from pcvfe_drake.models.data import DriveData
from pcvfe_drake.models.effects import Effect, SteeringLag
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.models.tyre_effects import PeakTyre
from pcvfe_drake.vehicle.params import ford_escort

pytest.importorskip("numba")

VP = ford_escort()
HORIZON = 40
SHIPPED = ("peak_tyre", "track_slip", "roll_camber", "wheel_force_steer", "axle_stiffness")
"""The effects of the shipped vehicle models (the context fitter's model)."""


def _drive(n: int = 400, seed: int = 0) -> DriveData:
    """Random states and inputs that reach every branch of the right-hand side: steering at
    its limits, speeds above the switching speed and near zero, commands beyond the limits,
    braking and driving, both cornering directions."""
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 7))
    x[:, 2] = rng.uniform(1.2 * VP.delta_min, 1.2 * VP.delta_max, n)
    x[:, 2] = np.clip(x[:, 2], VP.delta_min, VP.delta_max)
    x[:, 3] = rng.uniform(2.0, 2.5 * VP.v_switch, n)
    x[:, 4] = rng.uniform(-np.pi, np.pi, n)
    x[:, 5] = rng.normal(0.0, 0.6, n)
    x[:, 6] = rng.normal(0.0, 0.05, n)
    u = np.column_stack(
        [
            rng.uniform(1.5 * VP.delta_dot_min, 1.5 * VP.delta_dot_max, n),
            rng.uniform(-1.5 * VP.a_max, 1.5 * VP.a_max, n),
        ]
    )
    t = np.arange(n) * 0.01
    return DriveData(t, 0.01, x, u, np.zeros(n, dtype=int), ["all"], np.ones(7), "random")


def _both(model: WorkbenchModel, theta, data, starts):
    compiled = model.simulate(theta, data, starts, HORIZON)
    assert model._compiled_plan() is not None
    reference = WorkbenchModel(model.vehicle, model.effects, model.base_params, model.contexts)
    reference.compiled_rollout = False
    return compiled, reference.simulate(theta, data, starts, HORIZON)


SUBSETS = [()] + [(e,) for e in COMPILED_EFFECTS] + [tuple(COMPILED_EFFECTS)]
SUBSETS += [c for c in combinations(SHIPPED, 3)][:4]
# effects that share a hook compose in the model's order (both orders of each pair), and the
# library's diagnoses put a candidate beside those already selected
SUBSETS += [
    ("motor_power_limit", "rotating_inertia"),
    ("rotating_inertia", "motor_power_limit"),
    ("grade", "rolling_resistance", "drag"),
    ("friction_load", "friction_speed", "tire_saturation"),
    ("friction_speed", "friction_load", "peak_tyre"),
    ("tire_saturation", "peak_tyre"),
    ("peak_tyre", "tire_saturation", "axle_stiffness"),
    ("wheel_camber", "roll_camber", "track_slip", "peak_tyre"),
    ("track_slip", "wheel_camber", "tire_saturation", "friction_load"),
    ("steering_lag", "suspension_lag", "wheel_force_steer", "grade"),
    ("suspension_lag", "wheel_camber", "steering_lag", "input_delay", "gyro_bias"),
]


@pytest.mark.parametrize("effects", SUBSETS, ids=lambda s: "+".join(s) or "baseline")
def test_compiled_rollout_equals_the_numpy_rollout(effects):
    data = _drive()
    starts = np.arange(0, data.n - HORIZON - 1, 23)
    model = WorkbenchModel(VP, list(effects))
    rng = np.random.default_rng(len(effects))
    lo, hi = model.bounds()
    theta = np.tile(model.initial_theta(), (starts.size, 1))
    theta += 0.6 * (rng.uniform(lo, hi, theta.shape) - theta)  # parameters across the bounds
    compiled, reference = _both(model, theta, data, starts)
    assert np.all(np.isfinite(reference))
    # the same expressions in the same order: equal to the last bit where numpy and the
    # compiled code call the same functions; roll_camber's tanh (numpy's own vectorised one)
    # may differ in the last place
    np.testing.assert_allclose(compiled, reference, rtol=1e-11, atol=1e-12)


def test_effects_at_their_null_values():
    """Each effect at its null value (a lag of exactly 0: the lag's other branch) gives the
    numpy rollout's numbers, and the baseline's where the effect's null is exactly none."""
    data = _drive(seed=7)
    starts = np.arange(0, data.n - HORIZON - 1, 31)
    model = WorkbenchModel(VP, list(COMPILED_EFFECTS))
    theta = np.array([p.null if p.effect else p.initial for p in model.params])
    compiled, reference = _both(model, theta, data, starts)
    np.testing.assert_allclose(compiled, reference, rtol=1e-11, atol=1e-12)
    lags = WorkbenchModel(VP, ["steering_lag", "suspension_lag"])
    baseline = WorkbenchModel(VP, [])
    theta = np.array([p.null if p.effect else p.initial for p in lags.params])
    Z = lags.simulate(theta, data, starts, HORIZON)
    assert np.array_equal(Z[:, :, :7], baseline.simulate(theta[:1], data, starts, HORIZON))


def test_the_shipped_model_over_a_refit_s_rows_and_a_diverged_row():
    """The calibrated vehicle model as the context fitter rolls it out: nominal and
    finite-difference rows of mu; a row started from a non-finite state stays non-finite in
    both (a diverged rollout is caught by the fit)."""
    data = _drive(seed=2)
    model = WorkbenchModel(VP, list(SHIPPED))
    starts = np.array([10, 60, 150, 300])
    theta = np.tile(model.initial_theta(), (starts.size * 3, 1))
    theta[:, 0] = np.repeat([0.6, 0.6 + 1e-4, 0.6 - 1e-4], starts.size)
    all_starts = np.tile(starts, 3)
    compiled, reference = _both(model, theta, data, all_starts)
    np.testing.assert_allclose(compiled, reference, rtol=1e-11, atol=1e-12)
    x0 = data.x0[all_starts].copy()
    x0[1, 5] = np.nan
    out = model.simulate(theta, data, all_starts, HORIZON, x0=x0)
    model.compiled_rollout = False
    ref = model.simulate(theta, data, all_starts, HORIZON, x0=x0)
    assert np.array_equal(np.isfinite(out), np.isfinite(ref))
    assert not np.isfinite(out[1, -1]).all() and np.isfinite(np.delete(out, 1, axis=0)).all()


def test_effects_outside_the_loop_keep_the_compiled_rollout():
    """Sensor effects (measure / unmeasure) and an input hook act outside the RK4 loop."""
    data = _drive(seed=1)
    starts = np.arange(0, data.n - HORIZON - 1, 37)
    model = WorkbenchModel(VP, ["peak_tyre", "gyro_bias", "speed_scale", "input_delay"])
    theta = np.tile(model.initial_theta(), (starts.size, 1))
    names = model.param_names
    theta[:, names.index("gyro_bias.b")] = 0.01
    theta[:, names.index("speed_scale.k")] = 1.05
    theta[:, names.index("input_delay.T")] = 0.05
    compiled, reference = _both(model, theta, data, starts)
    np.testing.assert_allclose(compiled, reference, rtol=1e-11, atol=1e-12)


class FlatterPeakTyre(PeakTyre):
    shape = 1.2


class SlowerLag(SteeringLag):
    """A subclass of a compiled effect with its own states (it may change any hook)."""


class OwnState(Effect):
    """A user's effect with an own state (a first-order decay)."""

    name = "own_state"
    state_names = ("s",)

    def state_rates(self, ctx, delta_cmd, p):
        return -ctx.states

    def initial_states(self, data, starts, p):
        return np.ones((len(starts), 1))


class OtherTyre(Effect):
    """A user's tyre law."""

    name = "other_tyre"

    def tire(self, alpha, fz, c_alpha, p, ctx=None):
        return 0.9 * c_alpha * alpha


@pytest.mark.parametrize(
    "effects",
    [["peak_tyre", OwnState()], [SlowerLag()], [OtherTyre()], [FlatterPeakTyre()]],
    ids=["own_states", "lag_state", "other_tyre", "subclass"],
)
def test_other_effects_are_rolled_out_by_numpy(effects):
    model = WorkbenchModel(VP, effects)
    assert compiled_effect_plan(model.effects, model.vehicle) is None
    data = _drive(seed=3)
    starts = np.array([5, 100])
    Z = model.simulate(model.initial_theta(), data, starts, HORIZON)
    assert Z.shape == (2, HORIZON + 1, model.nz)


def test_a_subclass_with_another_constant_is_not_mistaken_for_the_shipped_effect():
    data = _drive(seed=4)
    starts = np.array([5, 100, 200])
    shipped = WorkbenchModel(VP, ["peak_tyre"])
    flatter = WorkbenchModel(VP, [FlatterPeakTyre()])
    theta = shipped.initial_theta()
    theta[0] = 0.4  # near the peak, where the shape factor matters
    a = shipped.simulate(theta, data, starts, HORIZON)
    b = flatter.simulate(theta, data, starts, HORIZON)
    flatter.compiled_rollout = False
    assert np.array_equal(b, flatter.simulate(theta, data, starts, HORIZON))
    assert not np.allclose(a, b)


@pytest.mark.parametrize(
    "effects",
    [
        (),
        ("peak_tyre",),
        tuple(SHIPPED),
        tuple(COMPILED_EFFECTS),
        ("tire_saturation", "friction_speed", "friction_load", "motor_power_limit"),
        ("peak_tyre", "wheel_camber", "suspension_lag", "steering_lag", "grade"),
    ],
    ids=["baseline", "peak_tyre", "shipped", "all", "brush_friction", "own_states"],
)
def test_the_exact_mu_sensitivity_is_the_limit_of_central_differences(effects):
    """The tangent carried through the compiled RK4 steps against central differences of the
    rollout at two steps: their gap is their truncation error, which falls with the square of
    the step (a wrong derivative would leave a gap that does not fall)."""
    data = _drive(seed=5)
    model = WorkbenchModel(VP, list(effects))
    starts = np.array([20, 90, 170, 260])
    theta = model.initial_theta()
    theta[0] = 0.45  # near the peak of the demanded forces: the tyre law is curved there
    Z, sens = model.mu_sensitivity(theta, data, starts, HORIZON)
    assert np.array_equal(Z, model.simulate(theta, data, starts, HORIZON))
    scale = np.maximum(np.abs(sens).max(axis=(0, 1)), 1e-12)
    gaps = []
    for step in (1e-3, 1e-4):
        up, down = theta.copy(), theta.copy()
        up[0] += step
        down[0] -= step
        fd = model.simulate(up, data, starts, HORIZON) - model.simulate(down, data, starts, HORIZON)
        gaps.append(np.max(np.abs(fd[:, :, :7] / (2 * step) - sens) / scale))
    assert gaps[1] < 1e-5
    assert gaps[1] < 0.05 * gaps[0] or gaps[0] < 1e-9


def test_a_fit_of_mu_alone_uses_the_exact_sensitivity():
    from pcvfe_drake.models.estimate import _residuals_and_jacobian

    data = _drive(seed=6)
    model = WorkbenchModel(VP, list(COMPILED_EFFECTS))
    starts = np.array([15, 120, 240])
    theta = model.initial_theta()
    theta[0] = 0.5
    r, jac = _residuals_and_jacobian(model, theta, data, starts, HORIZON, True, 5, np.array([0]))
    reference = WorkbenchModel(VP, list(COMPILED_EFFECTS))
    reference.compiled_rollout = False  # numpy: central differences
    r_fd, jac_fd = _residuals_and_jacobian(
        reference, theta, data, starts, HORIZON, True, 5, np.array([0])
    )
    np.testing.assert_allclose(r, r_fd, rtol=1e-9, atol=1e-9)
    assert np.count_nonzero(jac[:, 1:]) == 0
    np.testing.assert_allclose(jac[:, 0], jac_fd[:, 0], rtol=1e-4, atol=1e-6 * np.abs(jac).max())
    assert not np.array_equal(jac[:, 0], jac_fd[:, 0])  # exact, not the differences


def test_the_compiled_rollout_releases_the_gil():
    """The LCM station refits in a worker thread beside the loop's thread: the compiled rollout
    (most of a refit's arithmetic) must not hold the GIL, or the loop would wait for it."""
    from pcvfe_drake.models import compiled_kernel

    assert compiled_kernel.rollout_rows.targetoptions.get("nogil") is True
