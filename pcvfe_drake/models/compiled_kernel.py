"""The compiled rollout's kernel (numba): the right-hand side and the RK4 loop, on scalars.

Plain Python on floats, compiled by numba (:mod:`pcvfe_drake.models.compiled_rollout` says when
it runs and packs its arguments). Each expression keeps the numpy code's order of operations
(``models/model.py`` and the effects' hooks), so that the two paths give the same numbers.
Beside each value stands its derivative along the row's base ``mu`` (forward mode; ``d_``
names); it never feeds the values. The kernel is one module because numba's disk cache keys a
compiled function on its own file only: a callee in another file could change without the
caller being compiled again.

An effect is known by its code (its position in :data:`KERNEL_EFFECTS`); a model's effects
arrive as ``chains``: per group of hooks (:data:`CHAINS`) the codes of the effects that have
them, in the model's order (-1 ends a row), so that hooks several effects share compose in
the numpy code's order (sums and products in another order would differ in the last bits).
``col[code]`` is the effect's first column in a row's parameters ``q``, ``off[code]``
the index of its first own state in ``z`` (-1: none).
"""

from __future__ import annotations

import math

import numpy as np

try:  # numba is a dependency; without it (an unusual install) the numpy rollout runs
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

KERNEL_EFFECTS = (
    "peak_tyre",
    "track_slip",
    "roll_camber",
    "wheel_force_steer",
    "axle_stiffness",
    "drag",
    "rolling_resistance",
    "grade",
    "motor_power_limit",
    "rotating_inertia",
    "tire_saturation",
    "friction_speed",
    "friction_load",
    "wheel_camber",
    "steering_lag",
    "suspension_lag",
)
"""The effects the kernel evaluates, in the order of their codes."""

(PEAK, TRACK, ROLL, FORCE_STEER, AXLE, DRAG, ROLLING, GRADE, POWER, INERTIA, BRUSH,
 F_SPEED, F_LOAD, CAMBER, STEER_LAG, SUSP) = range(len(KERNEL_EFFECTS))  # fmt: skip

CHAINS = {
    "accel": ("motor_power_limit", "rotating_inertia"),
    "longitudinal": ("drag", "rolling_resistance", "grade"),
    "axle": ("friction_speed", "friction_load", "axle_stiffness", "peak_tyre", "tire_saturation"),
    "tire_offsets": ("roll_camber", "wheel_camber"),
    "wheel_slips": ("track_slip", "wheel_camber"),
}
"""The kernel's groups of hooks (the rows of ``chains``) and the effects in each: accel
hooks, longitudinal hooks, the axle's friction, stiffness and tyre law, tire_offsets hooks,
wheel_slips hooks."""
ACCEL, LONG, FRICTION, OFFSETS, SLIPS = range(len(CHAINS))

N_CONSTANTS = 28
"""Length of the constants vector ``vv`` (:func:`pcvfe_drake.models.compiled_rollout.constants`):
the vehicle's 15 fields, then the model's and the effects' constants."""
LOGE2 = 0.6931471805599453
"""log(2), as numpy's ``logaddexp`` adds it for equal arguments."""


def jit(fn=None, inline="never"):
    """Compiled with numba (IEEE arithmetic: no fast-math, numpy's error model), cached on
    disk; the plain function without numba (the rollout then runs numpy, the synthetic plant
    these functions uncompiled).
    ``inline="always"`` inlines it into its callers in numba's own IR: a call that passes
    arrays costs their reference counts, and LLVM does not inline a function this large."""
    if fn is None:
        return lambda f: jit(f, inline)
    if numba is None:
        return fn
    return numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False, inline=inline)(
        fn
    )


@jit
def _maximum(a, b):
    """np.maximum of two floats (NaN propagates: a diverged rollout stays NaN, as in numpy)."""
    return a if (a >= b or a != a) else b


@jit
def _minimum(a, b):
    """np.minimum of two floats (NaN propagates)."""
    return a if (a <= b or a != a) else b


@jit
def _sign(x):
    """np.sign of a float (0 at 0, NaN at NaN)."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x  # 0.0 or NaN


@jit
def _logaddexp0(y):
    """np.logaddexp(0.0, y), as numpy's ``npy_logaddexp`` forms it."""
    if y == 0.0:
        return 0.0 + LOGE2
    tmp = 0.0 - y
    if tmp > 0:
        return 0.0 + math.log1p(math.exp(-tmp))
    if tmp <= 0:
        return y + math.log1p(math.exp(tmp))
    return tmp


@jit
def _d_atan2(w, dw, u, du):
    return (u * dw - w * du) / (u * u + w * w)


@jit
def _peak_law(alpha, d_alpha, peak, d_peak, stiff, d_stiff, shape, tg):
    """peak_tyre's magic formula at slip ``alpha`` and its derivative (``tg``: else 0)."""
    shape_peak = shape * peak
    x = stiff * alpha / shape_peak
    angle = shape * math.atan(x)
    force = peak * math.sin(angle)
    if not tg:
        return force, 0.0
    dx = (d_stiff * alpha + stiff * d_alpha) / shape_peak - x * d_peak / peak
    return force, d_peak * math.sin(angle) + peak * math.cos(angle) * shape * dx / (1 + x * x)


@jit
def _brush_law(alpha, d_alpha, c_alpha, d_c_alpha, f_max, d_f_max, tg):
    """tire_saturation's brush law at slip ``alpha`` (peak ``f_max``) and its derivative
    (``tg``: else 0)."""
    z = c_alpha * alpha / (3.0 * f_max)
    za = _minimum(abs(z), 1.0)
    zs = _sign(z) * za
    bracket = zs - zs * za + zs**3.0 / 3.0
    if not tg:
        return 3.0 * f_max * bracket, 0.0
    dz = (d_c_alpha * alpha + c_alpha * d_alpha) / (3.0 * f_max) - z * d_f_max / f_max
    d_zs = dz if abs(z) < 1.0 else 0.0
    d_bracket = (1.0 - 2.0 * za + zs * zs) * d_zs
    return 3.0 * f_max * bracket, 3.0 * d_f_max * bracket + 3.0 * f_max * d_bracket


@jit
def _law(code, alpha, d_alpha, c_alpha, d_c_alpha, t0, t1, t2, t3, shape, tg):
    """The axle's law at slip ``alpha``: the tyre effect's (``code``; ``t0``-``t3`` its peak
    and stiffness with their derivatives), or the linear law (code -1)."""
    if code == PEAK:
        return _peak_law(alpha, d_alpha, t0, t1, t2, t3, shape, tg)
    if code == BRUSH:
        return _brush_law(alpha, d_alpha, c_alpha, d_c_alpha, t0, t1, tg)
    return c_alpha * alpha, d_c_alpha * alpha + c_alpha * d_alpha


@jit
def _camber_signs(a_roll, d_roll, a_x, d_x, k_x, width, tg):
    """wheel_camber's smooth signs (left, right) and their derivatives (``tg``: else 0)."""
    left = math.tanh((a_roll + k_x * a_x) / width)
    right = math.tanh((a_roll - k_x * a_x) / width)
    if not tg:
        return left, right, 0.0, 0.0
    d_left = (1.0 - left * left) * (d_roll + k_x * d_x) / width
    d_right = (1.0 - right * right) * (d_roll - k_x * d_x) / width
    return left, right, d_left, d_right


@jit(inline="always")
def _axle_force(
    front, fz, dfz, alpha, d_alpha, c_s, mu, dmu, z, dz, vv, q, chains, col, off, sh, tg
):
    """One axle's lateral force [N] and its derivative along mu (model.rhs steps 7 and 8 with
    the effects' hooks; ``sh``: what the axles share, values then derivatives)."""
    m, g, lf, lr, mu_nom = vv[11], vv[12], vv[8], vv[9], vv[14]
    v, r, dv, dr = z[3], z[5], dz[3], dz[5]
    a_long, d_long = sh[7], sh[17]
    lever = lf if front else -lr
    # 7. friction factors and the cornering stiffness
    scale, d_scale, hooked = 1.0, 0.0, False
    tyre_code = -1
    for j in range(chains.shape[1]):
        code = chains[FRICTION, j]
        if code < 0:
            break
        if code == F_SPEED or code == F_LOAD:
            k = q[col[code]]
            if code == F_SPEED:
                raw = 1.0 - k * (v - vv[20])
                d_raw = -k * dv
            else:
                wheelbase = lf + lr
                fz_static = m * g * lr / wheelbase if front else m * g * lf / wheelbase
                rel = fz / max(fz_static, 1.0) - 1.0
                raw = 1.0 - k * rel
                d_raw = -k * (dfz / max(fz_static, 1.0))
            factor = _maximum(raw, vv[21])
            d_factor = d_raw if raw >= vv[21] else 0.0
            d_scale = d_scale * factor + scale * d_factor
            scale = scale * factor
            hooked = True
        elif code == AXLE:
            c_s = c_s * (q[col[code]] if front else q[col[code] + 1])
        elif code == PEAK or code == BRUSH:
            tyre_code = code
    mu_a = mu * scale if hooked else mu
    d_mu_a = dmu * scale + mu * d_scale if hooked else dmu
    c_alpha = mu_a * c_s * fz
    d_c_alpha = d_mu_a * c_s * fz + mu_a * c_s * dfz
    t0 = t1 = t2 = t3 = 0.0  # the tyre law's peak and stiffness with derivatives
    if tyre_code == PEAK:
        mu_p = _maximum(mu, 1e-6)
        d_mu_p = dmu if mu >= 1e-6 else 0.0
        load = _maximum(fz, 1.0)
        d_load = dfz if fz >= 1.0 else 0.0
        t0 = mu_p * scale * load
        t1 = (d_mu_p * scale + mu_p * d_scale) * load + mu_p * scale * d_load
        exponent = 1.0 - q[col[PEAK]]
        ratio = mu_nom / mu_p
        t2 = c_alpha * ratio**exponent
        t3 = d_c_alpha * ratio**exponent
        if tg and exponent != 0.0:
            t3 += c_alpha * exponent * ratio ** (exponent - 1.0) * (-ratio * d_mu_p / mu_p)
    elif tyre_code == BRUSH:
        load = _maximum(fz, 1.0)
        d_load = dfz if fz >= 1.0 else 0.0
        t0 = q[col[BRUSH]] * scale * load
        t1 = q[col[BRUSH]] * (d_scale * load + scale * d_load)
    # 8. tire_offsets hooks (slip shift, side force), then wheel_slips hooks
    has_side, side, d_side = False, 0.0, 0.0
    for j in range(chains.shape[1]):
        code = chains[OFFSETS, j]
        if code < 0:
            break
        if code == ROLL:
            alpha = alpha + sh[0]
            d_alpha = d_alpha + sh[10]
            out, d_out = fz * sh[1], dfz * sh[1] + fz * sh[11]
        elif code == CAMBER:
            k_x = q[col[CAMBER] + 2] if front else q[col[CAMBER] + 3]
            s = off[CAMBER]
            left, right, dl, dr_ = _camber_signs(z[s], dz[s], a_long, d_long, k_x, vv[22], tg)
            f0 = q[col[CAMBER]]
            out = fz * f0 * 0.5 * (left + right)
            d_out = dfz * f0 * 0.5 * (left + right) + fz * f0 * 0.5 * (dl + dr_)
        else:
            continue
        if has_side:
            side, d_side = side + out, d_side + d_out
        else:
            side, d_side, has_side = out, d_out, True
    n_spread = 0
    s_l = s_r = share = d_l = d_r = d_share = 0.0
    for j in range(chains.shape[1]):
        code = chains[SLIPS, j]
        if code < 0:
            break
        if code == TRACK:
            w = sh[3] + lever * r
            dw = sh[13] + lever * dr
            centre = math.atan2(w, sh[2])
            o_l = centre - math.atan2(w, sh[4])
            o_r = centre - math.atan2(w, sh[5])
            do_l = do_r = 0.0
            if tg:
                d_centre = _d_atan2(w, dw, sh[2], sh[12])
                do_l = d_centre - _d_atan2(w, dw, sh[4], sh[14])
                do_r = d_centre - _d_atan2(w, dw, sh[5], sh[15])
            o_s, do_s = sh[6], sh[16]
        elif code == CAMBER:
            k_x = q[col[CAMBER] + 2] if front else q[col[CAMBER] + 3]
            s = off[CAMBER]
            left, right, dl, dr_ = _camber_signs(z[s], dz[s], a_long, d_long, k_x, vv[22], tg)
            s0 = q[col[CAMBER] + 1]
            o_l, o_r, do_l, do_r, o_s, do_s = s0 * left, s0 * right, s0 * dl, s0 * dr_, 0.5, 0.0
        else:
            continue
        if n_spread == 0:
            s_l, s_r, share, d_l, d_r, d_share = o_l, o_r, o_s, do_l, do_r, do_s
        else:
            s_l, s_r, share = s_l + o_l, s_r + o_r, share + o_s - 0.5
            d_l, d_r, d_share = d_l + do_l, d_r + do_r, d_share + do_s
        n_spread += 1
    shape = vv[16]
    if n_spread == 0:
        fy, dfy = _law(tyre_code, alpha, d_alpha, c_alpha, d_c_alpha, t0, t1, t2, t3, shape, tg)
    else:
        a_l, da_l, a_r, da_r = alpha + s_l, d_alpha + d_l, alpha + s_r, d_alpha + d_r
        f_l, df_l = _law(tyre_code, a_l, da_l, c_alpha, d_c_alpha, t0, t1, t2, t3, shape, tg)
        f_r, df_r = _law(tyre_code, a_r, da_r, c_alpha, d_c_alpha, t0, t1, t2, t3, shape, tg)
        fy = share * f_l + (1.0 - share) * f_r
        dfy = d_share * (f_l - f_r) + share * df_l + (1.0 - share) * df_r
    if has_side:
        fy, dfy = fy + side, dfy + d_side
    return fy, dfy


@jit(inline="always")
def _rhs(z, dz, u0, u1, vv, mu, dmu, c_sf, c_sr, q, chains, col, off, sh, K, D, st, tg):
    """One evaluation of the right-hand side for one row into ``K[st]`` (nz,), and its
    derivative along mu into ``D[st]`` for a state whose derivative along mu is ``dz`` and a mu
    whose is ``dmu`` (``tg``: else the derivatives are left out, 0); ``sh`` (20,) is scratch
    for what the axles share, values then derivatives."""
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
    # 2.-5. accel hooks, the wheel angle, longitudinal hooks, load transfer
    delta_w, d_delta_w = delta, d_delta
    for j in range(chains.shape[1]):
        code = chains[ACCEL, j]
        if code < 0:
            break
        if code == POWER:
            v_p = _maximum(v, vv[25])
            d_v_p = dv if v >= vv[25] else 0.0
            limit = 1000.0 * q[col[code]] / (m * v_p)
            d_limit = -limit * d_v_p / v_p
            if acc > 0:
                y = (acc - limit) / vv[24]
                if tg:
                    d_acc = d_acc - (d_acc - d_limit) / (1.0 + math.exp(-y))
                acc = acc - vv[24] * _logaddexp0(y)
        elif code == INERTIA:
            d_acc = d_acc * m / (m + q[col[code]])
            acc = acc * m / (m + q[col[code]])
    if off[STEER_LAG] >= 0:
        delta_w, d_delta_w = z[off[STEER_LAG]], dz[off[STEER_LAG]]
    a_long, d_long = acc, d_acc
    for j in range(chains.shape[1]):
        code = chains[LONG, j]
        if code < 0:
            break
        if code == DRAG:
            a_long = a_long + -0.5 * vv[19] * q[col[code]] * v * abs(v) / m
            d_long = d_long + -0.5 * vv[19] * q[col[code]] * 2.0 * abs(v) * dv / m
        elif code == ROLLING:
            s_v = math.tanh(v / vv[23])
            a_long = a_long + -q[col[code]] * g * s_v
            d_long = d_long + -q[col[code]] * g * (1.0 - s_v * s_v) * dv / vv[23]
        elif code == GRADE:
            gx, gy = q[col[code]], q[col[code] + 1]
            a_long = a_long + -g * (gx * math.cos(psi) + gy * math.sin(psi))
            if tg:
                d_long = d_long + -g * (-gx * math.sin(psi) + gy * math.cos(psi)) * d_psi
    a_load, d_load = a_long, d_long
    if off[SUSP] >= 0:
        w = _minimum(_maximum(q[col[SUSP]] / vv[26], 0.0), 1.0)
        s = off[SUSP]
        a_load, d_load = a_long + w * (z[s] - a_long), d_long + w * (dz[s] - d_long)
    sh[7], sh[17] = a_long, d_long
    # 5.-6. axle loads and slip angles
    vd = _maximum(v, v_floor)
    d_vd = dv if v >= v_floor else 0.0
    wheelbase = lf + lr
    fzf = m * (g * lr - a_load * hcg) / wheelbase
    fzr = m * (g * lf + a_load * hcg) / wheelbase
    d_fzf = -m * d_load * hcg / wheelbase
    alpha_f = delta_w - beta - lf * r / vd
    alpha_r = -beta + lr * r / vd
    d_yaw = (dr * vd - r * d_vd) / (vd * vd)
    d_alpha_f = d_delta_w - d_beta - lf * d_yaw
    d_alpha_r = -d_beta + lr * d_yaw
    # what both axles share: roll_camber's offsets, track_slip's wheel velocities
    if col[ROLL] >= 0:
        q0 = col[ROLL]
        a_dir = v * r
        da_dir = dv * r + v * dr
        s_dir = math.tanh(a_dir / roll_width)
        ds_dir = (1.0 - s_dir * s_dir) * da_dir / roll_width
        sh[0] = q[q0 + 2] * s_dir
        sh[1] = q[q0] * s_dir + q[q0 + 1] * a_dir / g
        sh[10] = q[q0 + 2] * ds_dir
        sh[11] = q[q0] * ds_dir + q[q0 + 1] * da_dir / g
    if col[TRACK] >= 0:
        q0 = col[TRACK]
        raw = q[q0 + 1] * v * r / g
        shift = _minimum(_maximum(raw, -max_shift), max_shift)
        d_shift = q[q0 + 1] * (dv * r + v * dr) / g if -max_shift < raw < max_shift else 0.0
        along = v * math.cos(beta)
        uu = _maximum(along, 0.5)
        d_uu = 0.0
        if tg and along >= 0.5:
            d_uu = dv * math.cos(beta) - v * math.sin(beta) * d_beta
        half = 0.5 * q[q0] * r
        d_half = 0.5 * q[q0] * dr
        floor = 0.1 * uu
        sh[2] = uu
        sh[3] = v * math.sin(beta)
        sh[4] = _maximum(uu + half, floor)
        sh[5] = _maximum(uu - half, floor)
        sh[6] = 0.5 * (1.0 - shift)
        sh[12] = d_uu
        sh[13] = dv * math.sin(beta) + v * math.cos(beta) * d_beta if tg else 0.0
        sh[14] = d_uu + d_half if uu + half >= floor else 0.1 * d_uu
        sh[15] = d_uu - d_half if uu - half >= floor else 0.1 * d_uu
        sh[16] = -0.5 * d_shift
    fyf = d_fyf = fyr = d_fyr = 0.0
    for axle in range(2):  # one call site: the axle's code is inlined once
        front = axle == 0
        fz, dfz = (fzf, d_fzf) if front else (fzr, -d_fzf)
        alpha, d_alpha = (alpha_f, d_alpha_f) if front else (alpha_r, d_alpha_r)
        fy, dfy = _axle_force(front, fz, dfz, alpha, d_alpha, c_sf if front else c_sr, mu, dmu,
                              z, dz, vv, q, chains, col, off, sh, tg)  # fmt: skip
        if front:
            fyf, d_fyf = fy, dfy
        else:
            fyr, d_fyr = fy, dfy
    # 9. body forces: wheel_force_steer
    a_x, d_x = a_long, d_long
    if col[FORCE_STEER] >= 0:
        q0 = col[FORCE_STEER]
        share = q[q0] if acc > 0 else q[q0 + 1]
        fxf = m * acc * share
        sin_d = math.sin(delta_w)
        d_sin = math.cos(delta_w) * d_delta_w if tg else 0.0
        da = -q[q0 + 2] * fyf * sin_d / m
        d_x = d_x - q[q0 + 2] * (d_fyf * sin_d + fyf * d_sin) / m
        d_fyf = d_fyf + m * d_acc * share * sin_d + fxf * d_sin
        fyf = fyf + fxf * sin_d
        a_x = a_x + da
    lateral = fyf + fyr
    course = psi + beta
    K[st, 0] = v * math.cos(course)
    K[st, 1] = v * math.sin(course)
    K[st, 2] = steer
    K[st, 3] = a_x
    K[st, 4] = r
    K[st, 5] = (lf * fyf - lr * fyr) / i_z
    K[st, 6] = lateral / (m * vd) - r
    if tg:
        d_course = d_psi + d_beta
        D[st, 0] = dv * math.cos(course) - v * math.sin(course) * d_course
        D[st, 1] = dv * math.sin(course) + v * math.cos(course) * d_course
    D[st, 2] = 0.0
    D[st, 3] = d_x
    D[st, 4] = dr
    D[st, 5] = (lf * d_fyf - lr * d_fyr) / i_z
    D[st, 6] = ((d_fyf + d_fyr) * m * vd - lateral * m * d_vd) / (m * vd) ** 2 - dr
    # 10. the effects' own states
    if off[STEER_LAG] >= 0:  # advanced exactly by the RK4 loop (_lag_at)
        K[st, off[STEER_LAG]] = 0.0
        D[st, off[STEER_LAG]] = 0.0
    if off[SUSP] >= 0:
        s = off[SUSP]
        tau = _maximum(q[col[SUSP]], vv[26])
        zeta = q[col[SUSP] + 1]
        K[st, s] = z[s + 1]
        K[st, s + 1] = (a_long - z[s]) / tau**2 - 2.0 * zeta * z[s + 1] / tau
        D[st, s] = dz[s + 1]
        D[st, s + 1] = (d_long - dz[s]) / tau**2 - 2.0 * zeta * dz[s + 1] / tau
    if off[CAMBER] >= 0:
        s = off[CAMBER]
        tau = _maximum(q[col[CAMBER] + 4], vv[27])
        K[st, s] = (lateral / m - z[s]) / tau
        D[st, s] = ((d_fyf + d_fyr) / m - dz[s]) / tau


@jit
def _lag_at(s0, ds0, start, d_start, stage, d_stage, offset, tau):
    """steering_lag's state ``offset`` seconds into a step that starts at ``s0`` with the
    angle ``start`` and reaches ``stage`` (``SteeringLag.states_at``), and its derivative."""
    slope = (stage - start) / offset
    d_slope = (d_stage - d_start) / offset
    e0 = s0 - start
    if tau > 1e-9:
        safe = _maximum(tau, 1e-12)
        decay = math.exp(-offset / safe)
        e = -safe * slope + (e0 + safe * slope) * decay
        de = -safe * d_slope + (ds0 - d_start + safe * d_slope) * decay
    else:
        e, de = 0.0, 0.0
    return stage + e, d_stage + de


@jit
def rollout_rows(Z, S, U, substeps, h, vv, mu, dmu, c_sf, c_sr, params, chains, col, off):
    """RK4 as WorkbenchModel.simulate's loop, one row after the other; with ``S`` (N,
    horizon + 1, 7) the ST states' derivatives along mu (``S[:, 0]`` given; ``dmu`` (N,) the
    rows' derivatives of mu: 1 for the differentiated rows), the same RK4 step differentiated
    (the derivative of the discrete rollout, as finite differences of it would approximate).
    The right-hand side has one call site (the stages in a loop), so that it is inlined once:
    compiled once, and no call passes arrays."""
    n, steps, nz = U.shape[0], U.shape[1], Z.shape[2]
    z, zs, dz, dzs = np.empty(nz), np.empty(nz), np.zeros(nz), np.zeros(nz)
    K, D = np.zeros((4, nz)), np.zeros((4, nz))  # the stages' rates and their derivatives
    sh = np.zeros(20)
    half = 0.5 * h
    sixth = h / 6.0
    tangent = S.shape[0] == n
    lag = off[STEER_LAG]
    for i in range(n):
        q = params[i]
        tau = q[col[STEER_LAG]] if lag >= 0 else 0.0
        mu_i, dmu_i, c_sf_i, c_sr_i = mu[i], dmu[i], c_sf[i], c_sr[i]
        for j in range(nz):
            z[j] = Z[i, 0, j]
            dz[j] = S[i, 0, j] if (tangent and j < 7) else 0.0
        for k in range(steps):
            u0, u1 = U[i, k, 0], U[i, k, 1]
            for _ in range(substeps):
                for st in range(4):
                    step = 0.0 if st == 0 else (h if st == 3 else half)
                    for j in range(nz):
                        zs[j] = z[j] + step * K[st - 1, j] if st else z[j]
                        dzs[j] = dz[j] + step * D[st - 1, j] if st else dz[j]
                    if lag >= 0 and st:  # the lag's state at the stage's time, exactly
                        zs[lag], dzs[lag] = _lag_at(z[lag], dz[lag], z[2], dz[2], zs[2], dzs[2],
                                                    step, tau)  # fmt: skip
                    _rhs(zs, dzs, u0, u1, vv, mu_i, dmu_i, c_sf_i, c_sr_i, q, chains, col, off,
                         sh, K, D, st, tangent)  # fmt: skip
                if lag >= 0:  # the step's start, for the lag's exact advance
                    s0, ds0, start, d_start = z[lag], dz[lag], z[2], dz[2]
                for j in range(nz):
                    z[j] = z[j] + sixth * (K[0, j] + 2.0 * K[1, j] + 2.0 * K[2, j] + K[3, j])
                    dz[j] = dz[j] + sixth * (D[0, j] + 2.0 * D[1, j] + 2.0 * D[2, j] + D[3, j])
                if lag >= 0:
                    z[lag], dz[lag] = _lag_at(s0, ds0, start, d_start, z[2], dz[2], h, tau)
            for j in range(nz):
                Z[i, k + 1, j] = z[j]
            if tangent:
                for j in range(7):
                    S[i, k + 1, j] = dz[j]
