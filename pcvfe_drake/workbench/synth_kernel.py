"""The synthetic truth plant's right-hand side and RK4 step, on scalars, compiled (numba).

:mod:`pcvfe_drake.workbench.synth` makes the planted drive logs with this plant: a log of
90-120 s at 20 Hz is about 58,000 evaluations of the right-hand side per truth, whose cost in
numpy was its per-call overhead on a handful of rows, not its arithmetic. Here each row (one
truth) is evaluated in plain Python on floats, compiled by numba (IEEE arithmetic, numpy's
error model, cached on disk); without numba the same functions run uncompiled.

A row's parameters ``q`` are the truth's columns in the order of :data:`TRUTH_COLUMNS`
(``synth.truth_columns`` gives them by name); the vehicle's are ``vv`` in the order of
:data:`VEHICLE_FIELDS`. A state row is ``[sx, sy, delta, v, psi, r, beta, delta_w]`` and
optionally the pitch mode's ``q, q'`` and the lagged lateral acceleration ``a_roll``
(8, 10 or 11 columns; ``synth._truth_rates`` documents the physics). Each row is its own
plant: which tyre law and whether the axles have two wheels follow from its own parameters.
"""

from __future__ import annotations

import math

import numpy as np

from pcvfe_drake.models.compiled_kernel import jit
from pcvfe_drake.models.effects import RHO_AIR_KGPM3

TRUTH_COLUMNS = (
    ("mu", math.nan),
    ("CdA", 0.0),
    ("c_rr", 0.0),
    ("steer_tau", 0.0),
    ("mu_peak", math.inf),
    ("gx", 0.0),
    ("gy", 0.0),
    ("p_max_kw", math.inf),
    ("mu_speed_slope", 0.0),
    ("mu_load_sens", 0.0),
    ("mf_peak", math.inf),
    ("mf_shape", 1.35),
    ("mf_exp", 0.0),
    ("k_f", 1.0),
    ("k_r", 1.0),
    ("m_rot", 0.0),
    ("ff_drive", 0.0),
    ("ff_brake", 0.0),
    ("ff_drag", 0.0),
    ("pitch_tau", 0.0),
    ("pitch_zeta", 1.0),
    ("cam_f0", 0.0),
    ("cam_f1", 0.0),
    ("cam_s0", 0.0),
    ("track_f", 0.0),
    ("track_r", 0.0),
    ("track_k_lt", 0.0),
    ("wcam_f0", 0.0),
    ("wcam_s0", 0.0),
    ("wcam_kf", 0.0),
    ("wcam_kr", 0.0),
    ("wcam_tau", 0.08),
)
"""The truth's parameter columns in the kernel's order, each with the value a column left out
of a partial set takes (``mu`` has none: it is always given)."""
(MU, CDA, CRR, STEER_TAU, MU_PEAK, GX, GY, P_MAX, MU_SPEED, MU_LOAD, MF_PEAK, MF_SHAPE, MF_EXP,
 K_F, K_R, M_ROT, FF_DRIVE, FF_BRAKE, FF_DRAG, PITCH_TAU, PITCH_ZETA, CAM_F0, CAM_F1, CAM_S0,
 TRACK_F, TRACK_R, TRACK_K_LT, WCAM_F0, WCAM_S0, WCAM_KF, WCAM_KR, WCAM_TAU) = range(
    len(TRUTH_COLUMNS))  # fmt: skip

VEHICLE_FIELDS = (
    "m",
    "g",
    "lf",
    "lr",
    "h",
    "I_z",
    "C_Sf",
    "C_Sr",
    "delta_min",
    "delta_max",
    "delta_dot_min",
    "delta_dot_max",
    "v_min",
    "v_max",
    "v_switch",
    "a_max",
)
"""The ``VehicleParams`` fields the plant reads, in the order of ``vv``."""


@jit
def _clip(x, lo, hi):
    """np.clip of a float."""
    return min(max(x, lo), hi)


@jit
def _brush(alpha, fz, c_alpha, mu_peak):
    """Lateral brush-tyre force [N]; linear where ``mu_peak`` is not finite."""
    if not math.isfinite(mu_peak):
        return c_alpha * alpha
    f_max = mu_peak * fz
    a = abs(alpha)
    if a < 3.0 * f_max / c_alpha:
        return (
            c_alpha * alpha
            - c_alpha**2 * alpha * a / (3.0 * f_max)
            + c_alpha**3.0 * alpha**3.0 / (27.0 * f_max**2)
        )
    return f_max * (1.0 if alpha > 0.0 else (-1.0 if alpha < 0.0 else 0.0))


@jit
def _axle(alpha, fz, mu_axle, c_s, peak_axle, q):
    """One axle's (or wheel's) lateral force [N]: the magic formula where the truth has one,
    else the brush tyre (linear without a peak)."""
    if not math.isfinite(q[MF_PEAK]):
        return _brush(alpha, fz, mu_axle * c_s * fz, peak_axle)
    follow = (q[MF_PEAK] / q[MU]) ** q[MF_EXP]
    d = q[MF_PEAK] / q[MU] * mu_axle * fz
    stiffness = follow * mu_axle * c_s * fz
    shape = q[MF_SHAPE]
    return d * math.sin(shape * math.atan(stiffness * alpha / (shape * d)))


@jit
def rates(s, out, steer_cmd, acc_cmd, q, vv):
    """The truth plant's derivative of one state row ``s`` into ``out`` (same length), under
    the commands ``[steer_cmd rad/s, acc_cmd m/s^2]`` (``synth._truth_rates``)."""
    m, g, lf, lr, hcg, i_z, c_sf, c_sr = vv[0], vv[1], vv[2], vv[3], vv[4], vv[5], vv[6], vv[7]
    n_cols = s.shape[0]
    delta, v, psi, r, beta, delta_w = s[2], s[3], s[4], s[5], s[6], s[7]
    pitched = q[PITCH_TAU] > 0
    # the vehicle's input constraints
    steer = _clip(steer_cmd, vv[10], vv[11])
    if (delta <= vv[8] and steer <= 0) or (delta >= vv[9] and steer >= 0):
        steer = 0.0
    upper = vv[15] * vv[14] / max(v, 1e-6) if v > vv[14] else vv[15]
    acc = _clip(acc_cmd, -vv[15], upper)
    if (v <= vv[12] and acc <= 0) or (v >= vv[13] and acc >= 0):
        acc = 0.0
    vs = max(v, 0.1)
    if acc > 0:
        acc = min(acc, 1000.0 * q[P_MAX] / (m * max(v, 0.5)))
    acc = acc * m / (m + q[M_ROT])
    wheel = delta_w if q[STEER_TAU] > 0 else delta
    wheelbase = lf + lr
    drag_force = 0.5 * RHO_AIR_KGPM3 * q[CDA] * v * abs(v)
    resist = m * g * (q[CRR] * math.tanh(v / 0.2))
    slope = m * g * (q[GX] * math.cos(psi) + q[GY] * math.sin(psi))
    # the load moves with the car's real longitudinal acceleration (resistances included)
    a_x = acc - (drag_force + resist + slope) / m
    fzf0 = m * g * lr / wheelbase
    fzr0 = m * g * lf / wheelbase
    a_pitch = a_x
    a_load = s[8] if (n_cols > 8 and pitched) else a_x
    fzf = fzf0 - m * a_load * hcg / wheelbase
    fzr = fzr0 + m * a_load * hcg / wheelbase
    # roll camber: the tyres see a shifted slip and get a side force per unit load
    a_lat = v * r
    turn = math.tanh(a_lat / 0.5)
    cam_shift = q[CAM_S0] * turn
    cam_side = q[CAM_F0] * turn + q[CAM_F1] * a_lat / g
    alpha_f = wheel - beta - lf * r / vs + cam_shift
    alpha_r = -beta + lr * r / vs + cam_shift
    mu_v = q[MU] * (1.0 - q[MU_SPEED] * (v - 15.0))
    mu_f = mu_v * (1.0 - q[MU_LOAD] * (fzf / fzf0 - 1.0))
    mu_r = mu_v * (1.0 - q[MU_LOAD] * (fzr / fzr0 - 1.0))
    peak_f = q[MU_PEAK] * mu_f / q[MU]
    peak_r = q[MU_PEAK] * mu_r / q[MU]
    csf = c_sf * q[K_F]
    csr = c_sr * q[K_R]
    # each wheel's camber sign from the lagged lateral and the longitudinal acceleration
    a_roll = s[10] if n_cols > 10 else 0.0
    k_xf, k_xr = q[WCAM_KF], q[WCAM_KR]
    sign_fl = math.tanh((a_roll + k_xf * a_x) / 0.1)
    sign_fr = math.tanh((a_roll - k_xf * a_x) / 0.1)
    sign_rl = math.tanh((a_roll + k_xr * a_x) / 0.1)
    sign_rr = math.tanh((a_roll - k_xr * a_x) / 0.1)
    track_f, track_r, s0 = q[TRACK_F], q[TRACK_R], q[WCAM_S0]
    if track_f > 0 or track_r > 0 or q[WCAM_F0] != 0 or s0 != 0:
        # two wheels per axle, t apart: each at its own slip, the outer one more loaded
        u_x = max(v * math.cos(beta), 0.5)
        w = v * math.sin(beta) + lf * r
        hf = 0.5 * track_f * r
        left_f = math.atan(w * hf / (u_x * (u_x + hf) + w * w)) + s0 * sign_fl
        right_f = math.atan(-w * hf / (u_x * (u_x - hf) + w * w)) + s0 * sign_fr
        w = v * math.sin(beta) + -lr * r
        hr = 0.5 * track_r * r
        left_r = math.atan(w * hr / (u_x * (u_x + hr) + w * w)) + s0 * sign_rl
        right_r = math.atan(-w * hr / (u_x * (u_x - hr) + w * w)) + s0 * sign_rr
        out_share = _clip(q[TRACK_K_LT] * a_lat / g, -0.9, 0.9)
        inner_left = 0.5 * (1.0 - out_share)  # a left bend: the left wheel inside
        fyf = inner_left * _axle(alpha_f + left_f, fzf, mu_f, csf, peak_f, q) + (
            1.0 - inner_left
        ) * _axle(alpha_f + right_f, fzf, mu_f, csf, peak_f, q)
        fyr = inner_left * _axle(alpha_r + left_r, fzr, mu_r, csr, peak_r, q) + (
            1.0 - inner_left
        ) * _axle(alpha_r + right_r, fzr, mu_r, csr, peak_r, q)
    else:
        fyf = _axle(alpha_f, fzf, mu_f, csf, peak_f, q)
        fyr = _axle(alpha_r, fzr, mu_r, csr, peak_r, q)
    fyf = fyf + (cam_side + 0.5 * q[WCAM_F0] * (sign_fl + sign_fr)) * fzf
    fyr = fyr + (cam_side + 0.5 * q[WCAM_F0] * (sign_rl + sign_rr)) * fzr
    sin_w = math.sin(wheel)
    fxf = m * acc * (q[FF_DRIVE] if acc > 0 else q[FF_BRAKE])
    a_x = a_x - q[FF_DRAG] * fyf * sin_w / m
    fyf = fyf + fxf * sin_w
    out[0] = v * math.cos(psi + beta)
    out[1] = v * math.sin(psi + beta)
    out[2] = steer
    out[3] = a_x
    out[4] = r
    out[5] = (lf * fyf - lr * fyr) / i_z
    out[6] = (fyf + fyr) / (m * vs) - r
    out[7] = (delta - delta_w) / max(q[STEER_TAU], 1e-6) if q[STEER_TAU] > 0 else 0.0
    if n_cols > 8:
        # the pitch mode, driven by the acceleration the loads follow without it
        tau = max(q[PITCH_TAU], 1e-6)
        if pitched:
            out[8] = s[9]
            out[9] = (a_pitch - s[8]) / tau**2 - 2.0 * q[PITCH_ZETA] * s[9] / tau
        else:
            out[8] = 0.0
            out[9] = 0.0
    if n_cols > 10:
        # the roll's lag of the lateral acceleration the axles' forces give
        out[10] = ((fyf + fyr) / m - a_roll) / max(q[WCAM_TAU], 1e-6)


@jit
def rates_rows(S, steer, acc, Q, vv, out):
    """:func:`rates` of every row of ``S`` (rows of ``Q`` its parameters) into ``out``."""
    for i in range(S.shape[0]):
        rates(S[i], out[i], steer[i], acc[i], Q[i], vv)


@jit
def _delayed(acc_log, i, k, t, delay, dt):
    """Row ``i``'s acceleration command at time ``t`` [s] through its dead time: the command
    logged at the last sample at or before ``t - delay``, at most sample ``k``."""
    idx = math.floor((t - delay) / dt + 1e-9)
    return acc_log[min(max(idx, 0), k), i]


@jit
def advance(S, Q, vv, steer, acc_log, delay, k, dt, substeps):
    """Advance every row of ``S`` in place from sample ``k`` to ``k + 1`` (``dt`` [s]) by
    ``substeps`` RK4 steps, the steering rate ``steer[i]`` held and the acceleration command
    read through each row's dead time ``delay[i]`` [s] from ``acc_log`` (samples, rows)."""
    n_cols = S.shape[1]
    h = dt / substeps
    stage = np.empty(n_cols)
    k1, k2, k3, k4 = np.empty(n_cols), np.empty(n_cols), np.empty(n_cols), np.empty(n_cols)
    for i in range(S.shape[0]):
        s, q, st = S[i], Q[i], steer[i]
        for j in range(substeps):
            t0 = k * dt + j * h
            rates(s, k1, st, _delayed(acc_log, i, k, t0, delay[i], dt), q, vv)
            for c in range(n_cols):
                stage[c] = s[c] + 0.5 * h * k1[c]
            rates(stage, k2, st, _delayed(acc_log, i, k, t0 + 0.5 * h, delay[i], dt), q, vv)
            for c in range(n_cols):
                stage[c] = s[c] + 0.5 * h * k2[c]
            rates(stage, k3, st, _delayed(acc_log, i, k, t0 + 0.5 * h, delay[i], dt), q, vv)
            for c in range(n_cols):
                stage[c] = s[c] + h * k3[c]
            rates(stage, k4, st, _delayed(acc_log, i, k, t0 + h, delay[i], dt), q, vv)
            for c in range(n_cols):
                s[c] = s[c] + h / 6.0 * (k1[c] + 2.0 * k2[c] + 2.0 * k3[c] + k4[c])
