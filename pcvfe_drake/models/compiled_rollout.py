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

Beside each expression of the right-hand side stands its derivative along the row's base
``mu`` (forward mode), so the same loop can carry the states' exact sensitivity to mu through
the RK4 steps (``WorkbenchModel.mu_sensitivity``: the derivative of the discrete rollout that
central differences approximate). The derivatives never feed the values: a rollout without
them gives the same numbers.

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
    from pcvfe_drake.models.effects import RHS_HOOKS, Effect
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


def load(model, plan: dict) -> None:
    """Compile the rollout, or load it from the disk cache, now (a tiny rollout of ``model``,
    whose :func:`compiled_effect_plan` is ``plan``) instead of in the first refit: a loop that
    starts with it loaded never waits for numba."""
    theta = np.atleast_2d(model.initial_theta())
    base, eff = model._unpack(theta, np.zeros(1, dtype=int))
    Z = np.zeros((1, 2, 7))
    Z[0, 0, 3] = 5.0
    rollout(Z, np.zeros((1, 1, 2)), 1, 0.01, model, base, eff, plan)


def _constants(vp, effects) -> np.ndarray:
    """The vehicle's parameters and the constants of the model and its effects, passed at run
    time (a compiled function's globals would be frozen into its disk cache)."""
    from pcvfe_drake.models.chassis_effects import MAX_LOAD_SHIFT
    from pcvfe_drake.models.effects import V_FLOOR_MPS
    from pcvfe_drake.models.tyre_effects import MF_SHAPE, ROLL_SIGN_WIDTH_MPS2

    shape = next((e.shape for e in effects if e.name == "peak_tyre"), MF_SHAPE)
    fixed = [V_FLOOR_MPS, shape, ROLL_SIGN_WIDTH_MPS2, MAX_LOAD_SHIFT]
    return np.array([float(getattr(vp, f)) for f in _VEHICLE_FIELDS] + fixed)


def rollout(Z, U, substeps: int, h: float, model, base: dict, eff: dict, plan: dict, S=None):
    """Fill ``Z[:, 1:, :7]`` (N, horizon + 1, 7) from ``Z[:, 0]`` under inputs ``U`` (N,
    horizon, 2): RK4 with ``substeps`` steps of ``h`` seconds per sample step, as
    :meth:`WorkbenchModel.simulate`'s loop; ``base`` and ``eff`` as its ``_unpack``. With
    ``S`` (N, horizon + 1, 7), ``S[:, 0]`` the start's, also fill ``S[:, 1:]`` with the
    states' derivatives along each row's base mu (forward mode through the same RK4 steps)."""
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
        np.zeros((0, 1, 7)) if S is None else S,
        np.ascontiguousarray(U, dtype=float),
        int(substeps),
        float(h),
        _constants(model.vehicle, model.effects),
        np.ascontiguousarray(base["mu"], dtype=float),
        np.zeros(n) if S is None else np.ones(n),
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
def _tyre(alpha, d_alpha, c_alpha, d_c_alpha, peak, d_peak, stiff, d_stiff, shape, has_peak):
    """The axle's law at slip ``alpha``: peak_tyre's magic formula, or the linear law; with
    its derivative along mu from the derivatives ``d_*`` of its inputs."""
    if has_peak:
        shape_peak = shape * peak
        x = stiff * alpha / shape_peak
        angle = shape * math.atan(x)
        dx = (d_stiff * alpha + stiff * d_alpha) / shape_peak - x * d_peak / peak
        force = peak * math.sin(angle)
        return force, d_peak * math.sin(angle) + peak * math.cos(angle) * shape * dx / (1 + x * x)
    return c_alpha * alpha, d_c_alpha * alpha + c_alpha * d_alpha


@_jit
def _d_atan2(w, dw, u, du):
    return (u * dw - w * du) / (u * u + w * w)


@_jit
def _axle_force(fz, dfz, alpha, d_alpha, c_s, lever, r, dr, mu, dmu, vv, q, has, sh):
    """One axle's lateral force [N] and its derivative along mu (model.rhs step 8 with the
    known effects' hooks; ``sh``: what the axles share, values and derivatives)."""
    has_peak, has_track, has_roll = has[0], has[1], has[2]
    mu_nom, shape = vv[14], vv[16]
    c_alpha = mu * c_s * fz
    d_c_alpha = dmu * c_s * fz + mu * c_s * dfz
    if has_roll:
        alpha = alpha + sh[0]
        d_alpha = d_alpha + sh[10]
    peak = d_peak = stiff = d_stiff = 0.0
    if has_peak:
        mu_p = _maximum(mu, 1e-6)
        d_mu_p = dmu if mu >= 1e-6 else 0.0
        load = _maximum(fz, 1.0)
        peak = mu_p * 1.0 * load
        d_peak = d_mu_p * load + mu_p * (dfz if fz >= 1.0 else 0.0)
        exponent = 1.0 - q[0]
        ratio = mu_nom / mu_p
        stiff = c_alpha * ratio**exponent
        d_ratio = -ratio * d_mu_p / mu_p
        d_stiff = d_c_alpha * ratio**exponent
        if exponent != 0.0:
            d_stiff += c_alpha * exponent * ratio ** (exponent - 1.0) * d_ratio
    if has_track:
        uu, side_v, u_left, u_right, share = sh[2], sh[3], sh[4], sh[5], sh[6]
        d_uu, d_side, d_left, d_right, d_share = sh[12], sh[13], sh[14], sh[15], sh[16]
        w = side_v + lever * r
        dw = d_side + lever * dr
        centre = math.atan2(w, uu)
        d_centre = _d_atan2(w, dw, uu, d_uu)
        a_left = alpha + (centre - math.atan2(w, u_left))
        da_left = d_alpha + (d_centre - _d_atan2(w, dw, u_left, d_left))
        a_right = alpha + (centre - math.atan2(w, u_right))
        da_right = d_alpha + (d_centre - _d_atan2(w, dw, u_right, d_right))
        f_l, df_l = _tyre(a_left, da_left, c_alpha, d_c_alpha, peak, d_peak, stiff, d_stiff,
                          shape, has_peak)  # fmt: skip
        f_r, df_r = _tyre(a_right, da_right, c_alpha, d_c_alpha, peak, d_peak, stiff, d_stiff,
                          shape, has_peak)  # fmt: skip
        fy = share * f_l + (1.0 - share) * f_r
        dfy = d_share * (f_l - f_r) + share * df_l + (1.0 - share) * df_r
    else:
        fy, dfy = _tyre(alpha, d_alpha, c_alpha, d_c_alpha, peak, d_peak, stiff, d_stiff,
                        shape, has_peak)  # fmt: skip
    if has_roll:
        fy = fy + fz * sh[1]
        dfy = dfy + dfz * sh[1] + fz * sh[11]
    return fy, dfy


@_jit
def _rhs(z, dz, u0, u1, vv, mu, dmu, c_sf, c_sr, q, has, sh, out, dout):
    """One evaluation of the right-hand side for one row into ``out`` (7,), and its
    derivative along mu into ``dout`` for a state whose derivative along mu is ``dz`` and a mu
    whose is ``dmu`` (the tangent, forward mode; its arithmetic never feeds the values);
    ``sh`` (20,) is scratch for what the axles share, values then derivatives."""
    delta_min, delta_max, ddot_min, ddot_max = vv[0], vv[1], vv[2], vv[3]
    v_switch, a_max, v_min, v_max = vv[4], vv[5], vv[6], vv[7]
    lf, lr, hcg, m, g, i_z = vv[8], vv[9], vv[10], vv[11], vv[12], vv[13]
    v_floor, roll_width, max_shift = vv[15], vv[17], vv[18]
    delta, v, psi, r, beta = z[2], z[3], z[4], z[5], z[6]
    d_delta, dv, d_psi, dr, d_beta = dz[2], dz[3], dz[4], dz[5], dz[6]
    # 1. the input constraints (model.applied_inputs); the steering rate does not depend on
    # the state but through its limits (a derivative of 0)
    steer = _minimum(_maximum(u0, ddot_min), ddot_max)
    if ((delta <= delta_min) and (steer <= 0)) or ((delta >= delta_max) and (steer >= 0)):
        steer = 0.0
    upper = (a_max * v_switch) / v if v > v_switch else a_max
    d_upper = -upper * dv / v if v > v_switch else 0.0
    acc = _minimum(_maximum(u1, -a_max), upper)
    d_acc = d_upper if (acc == upper and u1 > upper) else 0.0
    if ((v <= v_min) and (acc <= 0)) or ((v >= v_max) and (acc >= 0)):
        acc = 0.0
        d_acc = 0.0
    # 5.-6. axle loads and slip angles
    vd = _maximum(v, v_floor)
    d_vd = dv if v >= v_floor else 0.0
    wheelbase = lf + lr
    fzf = m * (g * lr - acc * hcg) / wheelbase
    fzr = m * (g * lf + acc * hcg) / wheelbase
    d_fzf = -m * d_acc * hcg / wheelbase
    alpha_f = delta - beta - lf * r / vd
    alpha_r = -beta + lr * r / vd
    d_yaw = (dr * vd - r * d_vd) / (vd * vd)
    d_alpha_f = d_delta - d_beta - lf * d_yaw
    d_alpha_r = -d_beta + lr * d_yaw
    # what both axles share: roll_camber's offsets, track_slip's wheel velocities
    if has[2]:
        a_dir = v * r
        da_dir = dv * r + v * dr
        s_dir = math.tanh(a_dir / roll_width)
        ds_dir = (1.0 - s_dir * s_dir) * da_dir / roll_width
        sh[0] = q[5] * s_dir
        sh[1] = q[3] * s_dir + q[4] * a_dir / g
        sh[10] = q[5] * ds_dir
        sh[11] = q[3] * ds_dir + q[4] * da_dir / g
    if has[1]:
        raw = q[2] * v * r / g
        shift = _minimum(_maximum(raw, -max_shift), max_shift)
        d_shift = q[2] * (dv * r + v * dr) / g if -max_shift < raw < max_shift else 0.0
        along = v * math.cos(beta)
        uu = _maximum(along, 0.5)
        d_uu = dv * math.cos(beta) - v * math.sin(beta) * d_beta if along >= 0.5 else 0.0
        half = 0.5 * q[1] * r
        d_half = 0.5 * q[1] * dr
        floor = 0.1 * uu
        sh[2] = uu
        sh[3] = v * math.sin(beta)
        sh[4] = _maximum(uu + half, floor)
        sh[5] = _maximum(uu - half, floor)
        sh[6] = 0.5 * (1.0 - shift)
        sh[12] = d_uu
        sh[13] = dv * math.sin(beta) + v * math.cos(beta) * d_beta
        sh[14] = d_uu + d_half if uu + half >= floor else 0.1 * d_uu
        sh[15] = d_uu - d_half if uu - half >= floor else 0.1 * d_uu
        sh[16] = -0.5 * d_shift
    if has[4]:  # axle_stiffness
        c_sf = c_sf * q[9]
        c_sr = c_sr * q[10]
    fyf, d_fyf = _axle_force(fzf, d_fzf, alpha_f, d_alpha_f, c_sf, lf, r, dr, mu, dmu, vv, q,
                             has, sh)  # fmt: skip
    fyr, d_fyr = _axle_force(fzr, -d_fzf, alpha_r, d_alpha_r, c_sr, -lr, r, dr, mu, dmu, vv, q,
                             has, sh)  # fmt: skip
    # 9. wheel_force_steer
    a_long = acc
    d_long = d_acc
    if has[3]:
        share = q[6] if acc > 0 else q[7]
        fxf = m * acc * share
        sin_d = math.sin(delta)
        d_sin = math.cos(delta) * d_delta
        da = -q[8] * fyf * sin_d / m
        d_long = d_long - q[8] * (d_fyf * sin_d + fyf * d_sin) / m
        d_fyf = d_fyf + m * d_acc * share * sin_d + fxf * d_sin
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
    d_course = d_psi + d_beta
    dout[0] = dv * math.cos(course) - v * math.sin(course) * d_course
    dout[1] = dv * math.sin(course) + v * math.cos(course) * d_course
    dout[2] = 0.0
    dout[3] = d_long
    dout[4] = dr
    dout[5] = (lf * d_fyf - lr * d_fyr) / i_z
    dout[6] = ((d_fyf + d_fyr) * m * vd - lateral * m * d_vd) / (m * vd) ** 2 - dr


@_jit
def _stage(z, dz, step, k, dk, zs, dzs):
    """An RK4 stage's state ``z + step k`` into ``zs``, its derivative into ``dzs``."""
    for j in range(7):
        zs[j] = z[j] + step * k[j]
        dzs[j] = dz[j] + step * dk[j]


@_jit
def _rollout_rows(Z, S, U, substeps, h, vv, mu, dmu, c_sf, c_sr, params, has):
    """RK4 as WorkbenchModel.simulate's loop, one row after the other; with ``S`` (N,
    horizon + 1, 7) the states' derivatives along mu (``S[:, 0]`` given; ``dmu`` (N,) the
    rows' derivatives of mu: 1 for the differentiated rows), the same RK4 step differentiated
    (the derivative of the discrete rollout, as finite differences of it would approximate)."""
    n, steps = U.shape[0], U.shape[1]
    z, zs, dz, dzs = np.empty(7), np.empty(7), np.zeros(7), np.zeros(7)
    k1, k2, k3, k4 = np.empty(7), np.empty(7), np.empty(7), np.empty(7)
    d1, d2, d3, d4 = np.zeros(7), np.zeros(7), np.zeros(7), np.zeros(7)
    sh = np.zeros(20)
    half = 0.5 * h
    sixth = h / 6.0
    tangent = S.shape[0] == n
    for i in range(n):
        q = params[i]
        mu_i, dmu_i, c_sf_i, c_sr_i = mu[i], dmu[i], c_sf[i], c_sr[i]
        for j in range(7):
            z[j] = Z[i, 0, j]
            dz[j] = S[i, 0, j] if tangent else 0.0
        for k in range(steps):
            u0, u1 = U[i, k, 0], U[i, k, 1]
            for _ in range(substeps):
                _rhs(z, dz, u0, u1, vv, mu_i, dmu_i, c_sf_i, c_sr_i, q, has, sh, k1, d1)
                _stage(z, dz, half, k1, d1, zs, dzs)
                _rhs(zs, dzs, u0, u1, vv, mu_i, dmu_i, c_sf_i, c_sr_i, q, has, sh, k2, d2)
                _stage(z, dz, half, k2, d2, zs, dzs)
                _rhs(zs, dzs, u0, u1, vv, mu_i, dmu_i, c_sf_i, c_sr_i, q, has, sh, k3, d3)
                _stage(z, dz, h, k3, d3, zs, dzs)
                _rhs(zs, dzs, u0, u1, vv, mu_i, dmu_i, c_sf_i, c_sr_i, q, has, sh, k4, d4)
                for j in range(7):
                    z[j] = z[j] + sixth * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
                    dz[j] = dz[j] + sixth * (d1[j] + 2.0 * d2[j] + 2.0 * d3[j] + d4[j])
            for j in range(7):
                Z[i, k + 1, j] = z[j]
                if tangent:
                    S[i, k + 1, j] = dz[j]
