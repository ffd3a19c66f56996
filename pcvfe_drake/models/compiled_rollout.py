"""The workbench model's RK4 rollout compiled (numba): the same arithmetic, row by row.

A refit rolls the model out over a handful of windows, where the numpy right-hand side
(:meth:`~pcvfe_drake.models.model.WorkbenchModel.rhs`) costs numpy's per-call overhead (about
150 calls per evaluation, 400 evaluations per rollout), not its arithmetic. This module runs
the whole RK4 loop of :meth:`~pcvfe_drake.models.model.WorkbenchModel.simulate` in one
compiled function for the base model and the effects it knows (:data:`COMPILED_EFFECTS`: the
effects of the shipped vehicle models), with each expression written in the numpy code's
order of operations, so that the two paths give the same numbers: to the last bit where
both call the same library functions (``sin``, ``cos``, ``atan``, ``atan2``, ``pow``), within
a few units in the last place where numpy has its own vectorised function (``tanh``, used
by ``roll_camber``); ``tests/models/test_compiled_rollout.py`` compares them.

A model with any other effect that changes the right-hand side (its own hooks, states, or a
subclass of a known effect) is rolled out by the numpy code; hooks outside the RK4 loop
(``inputs``, ``measure``, ``unmeasure``) stay in numpy either way. Without numba the numpy
code runs. The compiled function is cached on disk (``cache=True``): a process compiles it
once per installation, later ones load it. It releases the GIL (``nogil``), so a refit in a
worker thread does not hold up the loop's thread.
"""

from __future__ import annotations

import math

import numpy as np

try:  # numba is a dependency; without it (an unusual install) the numpy rollout runs
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

COMPILED_EFFECTS = (
    "peak_tyre",
    "track_slip",
    "roll_camber",
    "wheel_force_steer",
    "axle_stiffness",
)
"""Effects the compiled rollout evaluates (their registered classes exactly)."""

# Columns of the effect-parameter matrix passed to the kernel, and of the vehicle vector.
_EFFECT_COLUMNS = {
    "peak_tyre": ("k_s",),
    "track_slip": ("t", "k_lt"),
    "roll_camber": ("f0", "f1", "s0"),
    "wheel_force_steer": ("s_drive", "s_brake", "k_drag"),
    "axle_stiffness": ("k_f", "k_r"),
}
_VEHICLE_FIELDS = (
    "delta_min",
    "delta_max",
    "delta_dot_min",
    "delta_dot_max",
    "v_switch",
    "a_max",
    "v_min",
    "v_max",
    "lf",
    "lr",
    "h",
    "m",
    "g",
    "I_z",
    "mu",
)


def compiled_effect_plan(effects) -> dict | None:
    """Which known effects a model has (name -> bool), or None when its right-hand side needs
    the numpy code: numba is missing, or an effect that changes the right-hand side (its
    hooks, own states) is not one of :data:`COMPILED_EFFECTS`' classes
    exactly (a subclass may change any hook or constant)."""
    if numba is None:
        return None
    from pcvfe_drake.models.chassis_effects import AxleStiffness, TrackSlip, WheelForceSteer
    from pcvfe_drake.models.effects import Effect
    from pcvfe_drake.models.model import RHS_HOOKS
    from pcvfe_drake.models.tyre_effects import PeakTyre, RollCamber

    known = (PeakTyre, TrackSlip, RollCamber, WheelForceSteer, AxleStiffness)
    hooks = (*RHS_HOOKS, "state_rates", "states_at")
    present = dict.fromkeys(COMPILED_EFFECTS, False)
    for e in effects:
        if type(e) in known:
            present[e.name] = True
        elif e.n_states or any(getattr(type(e), h) is not getattr(Effect, h) for h in hooks):
            return None
    return present


def load(model) -> bool:
    """Compile the rollout, or load it from the disk cache, now (a tiny rollout of ``model``)
    instead of in the first refit: a loop that starts with it loaded never waits for numba.
    False when the model's rollout is not compiled."""
    plan = compiled_effect_plan(model.effects)
    if plan is None:
        return False
    theta = np.atleast_2d(model.initial_theta())
    base, eff = model._unpack(theta, np.zeros(1, dtype=int))
    Z = np.zeros((1, 2, 7))
    Z[0, 0, 3] = 5.0
    rollout(Z, np.zeros((1, 1, 2)), 1, 0.01, model, base, eff, plan)
    return True


def _constants(vp, effects) -> np.ndarray:
    """The vehicle's parameters and the constants of the model and its effects, passed at run
    time (a compiled function's globals would be frozen into its disk cache)."""
    from pcvfe_drake.models.chassis_effects import MAX_LOAD_SHIFT
    from pcvfe_drake.models.model import V_FLOOR_MPS
    from pcvfe_drake.models.tyre_effects import MF_SHAPE, ROLL_SIGN_WIDTH_MPS2

    shape = next((e.shape for e in effects if e.name == "peak_tyre"), MF_SHAPE)
    fixed = [V_FLOOR_MPS, shape, ROLL_SIGN_WIDTH_MPS2, MAX_LOAD_SHIFT]
    return np.array([float(getattr(vp, f)) for f in _VEHICLE_FIELDS] + fixed)


def rollout(Z, U, substeps: int, h: float, model, base: dict, eff: dict, plan: dict) -> None:
    """Fill ``Z[:, 1:, :7]`` (N, horizon + 1, 7) from ``Z[:, 0]`` under inputs ``U`` (N,
    horizon, 2): RK4 with ``substeps`` steps of ``h`` seconds per sample step, as
    :meth:`WorkbenchModel.simulate`'s loop; ``base`` and ``eff`` as its ``_unpack``."""
    n = Z.shape[0]
    cols = [
        eff[name][p] if plan[name] else np.zeros(n)
        for name in COMPILED_EFFECTS
        for p in _EFFECT_COLUMNS[name]
    ]
    params = np.ascontiguousarray(np.stack(cols, axis=1), dtype=float)
    flags = np.array([plan[name] for name in COMPILED_EFFECTS], dtype=np.bool_)
    _rollout_rows(
        Z,
        np.ascontiguousarray(U, dtype=float),
        int(substeps),
        float(h),
        _constants(model.vehicle, model.effects),
        np.ascontiguousarray(base["mu"], dtype=float),
        np.ascontiguousarray(base["C_Sf"], dtype=float),
        np.ascontiguousarray(base["C_Sr"], dtype=float),
        params,
        flags,
    )


def _jit(fn):
    """Compiled with numba (IEEE arithmetic: no fast-math, numpy's error model), cached on
    disk; the plain function without numba (then never called: the plan is None)."""
    if numba is None:
        return fn
    return numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False)(fn)


# --- the kernel: plain Python on scalars, compiled by numba -----------------------------------
# Each expression keeps the numpy code's order of operations (model.py and the effects).


@_jit
def _maximum(a, b):
    """np.maximum of two floats (NaN propagates: a diverged rollout stays NaN, as in numpy)."""
    return a if (a >= b or a != a) else b


@_jit
def _minimum(a, b):
    """np.minimum of two floats (NaN propagates)."""
    return a if (a <= b or a != a) else b


@_jit
def _tyre(alpha, c_alpha, peak, stiffness, shape, shape_peak, has_peak):
    """The axle's law at slip ``alpha``: peak_tyre's magic formula, or the linear law."""
    if has_peak:
        return peak * math.sin(shape * math.atan(stiffness * alpha / shape_peak))
    return c_alpha * alpha


@_jit
def _axle_force(fz, alpha, c_s, lever, r, mu, mu_nom, shape, q, has, roll, track):
    """One axle's lateral force [N] (model.rhs step 8 with the known effects' hooks)."""
    has_peak, has_track, has_roll = has[0], has[1], has[2]
    c_alpha = mu * c_s * fz
    if has_roll:
        alpha = alpha + roll[0]
    peak = 0.0
    stiffness = 0.0
    shape_peak = 0.0
    if has_peak:
        mu_p = _maximum(mu, 1e-6)
        peak = mu_p * 1.0 * _maximum(fz, 1.0)
        stiffness = c_alpha * (mu_nom / mu_p) ** (1.0 - q[0])
        shape_peak = shape * peak
    if has_track:
        uu, side_v, u_left, u_right, share = track[0], track[1], track[2], track[3], track[4]
        w = side_v + lever * r
        centre = math.atan2(w, uu)
        a_left = alpha + (centre - math.atan2(w, u_left))
        a_right = alpha + (centre - math.atan2(w, u_right))
        f_left = _tyre(a_left, c_alpha, peak, stiffness, shape, shape_peak, has_peak)
        f_right = _tyre(a_right, c_alpha, peak, stiffness, shape, shape_peak, has_peak)
        fy = share * f_left + (1.0 - share) * f_right
    else:
        fy = _tyre(alpha, c_alpha, peak, stiffness, shape, shape_peak, has_peak)
    if has_roll:
        fy = fy + fz * roll[1]
    return fy


@_jit
def _rhs(z, u0, u1, vv, mu, c_sf, c_sr, q, has, roll, track, out):
    """One evaluation of the right-hand side for one row into ``out`` (7,); ``roll`` (2,) and
    ``track`` (5,) are scratch for what the axles share."""
    delta_min, delta_max, ddot_min, ddot_max = vv[0], vv[1], vv[2], vv[3]
    v_switch, a_max, v_min, v_max = vv[4], vv[5], vv[6], vv[7]
    lf, lr, hcg, m, g, i_z, mu_nom = vv[8], vv[9], vv[10], vv[11], vv[12], vv[13], vv[14]
    v_floor, shape, roll_width, max_shift = vv[15], vv[16], vv[17], vv[18]
    delta, v, psi, r, beta = z[2], z[3], z[4], z[5], z[6]
    # 1. the input constraints (model.applied_inputs)
    steer = _minimum(_maximum(u0, ddot_min), ddot_max)
    if ((delta <= delta_min) and (steer <= 0)) or ((delta >= delta_max) and (steer >= 0)):
        steer = 0.0
    upper = (a_max * v_switch) / v if v > v_switch else a_max
    acc = _minimum(_maximum(u1, -a_max), upper)
    if ((v <= v_min) and (acc <= 0)) or ((v >= v_max) and (acc >= 0)):
        acc = 0.0
    # 5.-6. axle loads and slip angles
    vd = _maximum(v, v_floor)
    wheelbase = lf + lr
    fzf = m * (g * lr - acc * hcg) / wheelbase
    fzr = m * (g * lf + acc * hcg) / wheelbase
    alpha_f = delta - beta - lf * r / vd
    alpha_r = -beta + lr * r / vd
    # what both axles share: roll_camber's offsets, track_slip's wheel velocities
    if has[2]:
        a_dir = v * r
        s_dir = math.tanh(a_dir / roll_width)
        roll[0] = q[5] * s_dir
        roll[1] = q[3] * s_dir + q[4] * a_dir / g
    if has[1]:
        shift = _minimum(_maximum(q[2] * v * r / g, -max_shift), max_shift)
        uu = _maximum(v * math.cos(beta), 0.5)
        half = 0.5 * q[1] * r
        floor = 0.1 * uu
        track[0] = uu
        track[1] = v * math.sin(beta)
        track[2] = _maximum(uu + half, floor)
        track[3] = _maximum(uu - half, floor)
        track[4] = 0.5 * (1.0 - shift)
    if has[4]:  # axle_stiffness
        c_sf = c_sf * q[9]
        c_sr = c_sr * q[10]
    fyf = _axle_force(fzf, alpha_f, c_sf, lf, r, mu, mu_nom, shape, q, has, roll, track)
    fyr = _axle_force(fzr, alpha_r, c_sr, -lr, r, mu, mu_nom, shape, q, has, roll, track)
    # 9. wheel_force_steer
    a_long = acc
    if has[3]:
        fxf = m * acc * (q[6] if acc > 0 else q[7])
        sin_d = math.sin(delta)
        da = -q[8] * fyf * sin_d / m
        fyf = fyf + fxf * sin_d
        a_long = a_long + da
    lateral = fyf + fyr
    course = psi + beta
    out[0] = v * math.cos(course)
    out[1] = v * math.sin(course)
    out[2] = steer
    out[3] = a_long
    out[4] = r
    out[5] = (lf * fyf - lr * fyr) / i_z
    out[6] = lateral / (m * vd) - r


@_jit
def _rollout_rows(Z, U, substeps, h, vv, mu, c_sf, c_sr, params, has):
    """RK4 as WorkbenchModel.simulate's loop, one row after the other."""
    n, steps = U.shape[0], U.shape[1]
    z = np.empty(7)
    zs = np.empty(7)
    k1, k2, k3, k4 = np.empty(7), np.empty(7), np.empty(7), np.empty(7)
    roll, track = np.zeros(2), np.zeros(5)
    half = 0.5 * h
    sixth = h / 6.0
    for i in range(n):
        q = params[i]
        mu_i, c_sf_i, c_sr_i = mu[i], c_sf[i], c_sr[i]
        for j in range(7):
            z[j] = Z[i, 0, j]
        for k in range(steps):
            u0, u1 = U[i, k, 0], U[i, k, 1]
            for _ in range(substeps):
                _rhs(z, u0, u1, vv, mu_i, c_sf_i, c_sr_i, q, has, roll, track, k1)
                for j in range(7):
                    zs[j] = z[j] + half * k1[j]
                _rhs(zs, u0, u1, vv, mu_i, c_sf_i, c_sr_i, q, has, roll, track, k2)
                for j in range(7):
                    zs[j] = z[j] + half * k2[j]
                _rhs(zs, u0, u1, vv, mu_i, c_sf_i, c_sr_i, q, has, roll, track, k3)
                for j in range(7):
                    zs[j] = z[j] + h * k3[j]
                _rhs(zs, u0, u1, vv, mu_i, c_sf_i, c_sr_i, q, has, roll, track, k4)
                for j in range(7):
                    z[j] = z[j] + sixth * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
            for j in range(7):
                Z[i, k + 1, j] = z[j]
