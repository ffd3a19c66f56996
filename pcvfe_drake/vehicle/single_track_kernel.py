"""The single-track model's derivative and exact Jacobians compiled (numba), row by row.

``single_track.st_jacobians`` evaluates a batch with about 200 numpy calls whatever its size;
the NMPC linearises 40 states at every update, where those calls' overhead, not their
arithmetic, is the cost (about 0.3 ms of the update's 5 ms). This kernel runs the same
expressions on one state at a time, in the numpy code's order of operations (each product,
sum and quotient in the order ``single_track._evaluate`` writes it, the vehicle's scalar
products formed once in Python, as there), so that the two give the same numbers to the last
bit (``tests/vehicle/test_single_track.py`` compares them).

It covers a batch in the purely dynamic range (every speed at least ``V_BLEND_HI``), where
``_evaluate`` computes no kinematic term: the kinematic model's values enter its Jacobian
expressions as zeros, and so they do here (a product with zero is not dropped, so the signs
and the roundings stay numpy's). A batch with a slower state takes the numpy code, whose
``tan``, ``arctan`` and fractional powers are numpy's own and differ in the last bits from the
C library's that a compiled function calls. One module, because numba's disk cache keys a
compiled function on its own file.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import (
    BETA,
    DELTA,
    NTHETA,
    NU,
    NX,
    PSI,
    PSI_DOT,
    SX,
    SY,
    V_BLEND_HI,
    V_BLEND_LO,
    V,
)

try:  # numba is a dependency; without it (an unusual install) the numpy code runs
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

(
    K_M,
    K_LF,
    K_LR,
    K_H,
    K_WHEELBASE,
    K_G_LR,
    K_G_LF,
    K_IZ_WHEELBASE,
    K_LF2,
    K_LR2,
    K_NEG_LF,
    K_NEG_LF2,
    K_M_IZ_WHEELBASE,
    K_DELTA_MIN,
    K_DELTA_MAX,
    K_DELTA_DOT_MIN,
    K_DELTA_DOT_MAX,
    K_NEG_A_MAX,
    K_V_SWITCH,
    K_A_MAX_V_SWITCH,
    K_V_MIN,
    K_V_MAX,
    K_V_BLEND_LO,
    K_SPAN,
) = range(24)
N_CONSTANTS = 24
"""The kernel's constants (:func:`kernel_constants` forms them)."""


def _dynamic_row(A, B, i, row, w, d_delta, d_beta, d_r, d_vd, d_acc, dvd_dv, d_acc_dv, d_acc_du1):
    """The dynamic part of row ``row`` (yaw acceleration or slip rate) of state ``i``'s A and B
    from its partial derivatives (``_evaluate``'s loop over the two rows)."""
    A[i, row, DELTA] = w * d_delta
    A[i, row, BETA] = w * d_beta
    A[i, row, PSI_DOT] = w * d_r
    A[i, row, V] = w * (d_vd * dvd_dv + d_acc * d_acc_dv)
    B[i, row, 1] = w * d_acc * d_acc_du1


def _rows(x, u, theta, k, f, A, B, P):  # pragma: no cover - compiled; tested through st_jacobians
    """f (N,7), A (N,7,7), B (N,7,2), P (N,7,3) of the dynamic range's rows; A, B and P are
    zeros on entry. ``theta`` has one row or N."""
    m, lf, lr, h, wheelbase = k[K_M], k[K_LF], k[K_LR], k[K_H], k[K_WHEELBASE]
    one_theta = theta.shape[0] == 1
    for i in range(x.shape[0]):
        j = 0 if one_theta else i
        delta, v, psi, r, beta = x[i, DELTA], x[i, V], x[i, PSI], x[i, PSI_DOT], x[i, BETA]
        u0, u1 = u[i, 0], u[i, 1]
        mu, c_sf, c_sr = theta[j, 0], theta[j, 1], theta[j, 2]
        # _constrained
        steer = min(max(u0, k[K_DELTA_DOT_MIN]), k[K_DELTA_DOT_MAX])
        pos_limit = k[K_A_MAX_V_SWITCH] / max(v, k[K_V_SWITCH])
        acc = min(max(u1, k[K_NEG_A_MAX]), pos_limit)
        steer_stop = (delta <= k[K_DELTA_MIN] and u0 <= 0) or (delta >= k[K_DELTA_MAX] and u0 >= 0)
        if steer_stop:
            steer = 0.0
        acc_stop = (v <= k[K_V_MIN] and u1 <= 0) or (v >= k[K_V_MAX] and u1 >= 0)
        if acc_stop:
            acc = 0.0
        d_steer = 0.0 if steer_stop or u0 <= k[K_DELTA_DOT_MIN] or u0 >= k[K_DELTA_DOT_MAX] else 1.0
        acc_low = (not acc_stop) and u1 <= k[K_NEG_A_MAX]
        acc_high = (not acc_stop) and (not acc_low) and u1 >= pos_limit
        d_acc_du1 = 0.0 if acc_stop or acc_low or acc_high else 1.0
        d_acc_dv = -pos_limit / max(v, k[K_V_SWITCH]) if acc_high and v > k[K_V_SWITCH] else 0.0
        # the dynamic model
        vd = max(v, k[K_V_BLEND_LO])
        gf = k[K_G_LR] - acc * h
        gr = k[K_G_LF] + acc * h
        ff = c_sf * gf
        fr = c_sr * gr
        k_yaw = mu * m / k[K_IZ_WHEELBASE]
        yaw_sum = k[K_LF2] * ff + k[K_LR2] * fr
        moment = lr * fr - lf * ff
        r_v = r / vd
        dd_psi_dyn = k_yaw * ((lf * ff) * delta + moment * beta - yaw_sum * r_v)
        k_slip = mu / (vd * wheelbase)
        slip_sum = ff * delta - (fr + ff) * beta + moment * r_v
        d_beta_dyn = k_slip * slip_sum - r
        cos_dyn = np.cos(psi + beta)
        sin_dyn = np.sin(psi + beta)
        s = min(max((v - k[K_V_BLEND_LO]) / k[K_SPAN], 0.0), 1.0)
        w = s * s * (3.0 - 2.0 * s)
        dw = 6.0 * s * (1.0 - s) / k[K_SPAN]
        f[i, SX] = v * cos_dyn
        f[i, SY] = v * sin_dyn
        f[i, DELTA] = steer
        f[i, V] = acc
        f[i, PSI] = r
        f[i, PSI_DOT] = dd_psi_dyn
        f[i, BETA] = d_beta_dyn
        dvd_dv = 1.0 if v > k[K_V_BLEND_LO] else 0.0
        vd2 = vd * vd
        psi_delta = k_yaw * lf * ff
        psi_beta = k_yaw * moment
        psi_r = -k_yaw * yaw_sum / vd
        psi_vd = k_yaw * yaw_sum * r / vd2
        psi_acc = k_yaw * (
            k[K_NEG_LF] * c_sf * h * delta
            + (lr * c_sr * h + lf * c_sf * h) * beta
            - (k[K_NEG_LF2] * c_sf * h + k[K_LR2] * c_sr * h) * r / vd
        )
        psi_mu = k[K_M_IZ_WHEELBASE] * (lf * ff * delta + moment * beta - yaw_sum * r / vd)
        psi_c_sf = k_yaw * (lf * gf * delta - lf * gf * beta - k[K_LF2] * gf * r / vd)
        psi_c_sr = k_yaw * (lr * gr * beta - k[K_LR2] * gr * r / vd)
        beta_delta = k_slip * ff
        beta_beta = -k_slip * (fr + ff)
        beta_r = k_slip * moment / vd - 1.0
        beta_vd = -k_slip / vd * slip_sum - k_slip * moment * r / vd2
        beta_acc = k_slip * (
            -c_sf * h * delta
            - (c_sr * h - c_sf * h) * beta
            + (lr * c_sr * h + lf * c_sf * h) * r / vd
        )
        beta_mu = slip_sum / (vd * wheelbase)
        beta_c_sf = k_slip * (gf * delta - gf * beta - lf * gf * r / vd)
        beta_c_sr = k_slip * (-gr * beta + lr * gr * r / vd)
        # the kinematic terms' values where none is computed (numpy's zeros and ones)
        c, t, sec2, q, gk, gk_t = 0.0, 0.0, 0.0, 1.0, 0.0, 0.0
        slip_rate_k = psi_dot_k = d_beta_kin = dd_psi_kin = 0.0
        cos_kin = sin_kin = 0.0
        wk = 1.0 - w
        dslip_rate_k_dt = 2.0 * c * t * (1.0 - c * c) / (q * q)
        gk_tt = -3.0 * c * c * t * q**-2.5
        d_psi_dot_k_ddelta = v * gk_t * sec2 / wheelbase
        d_dd_psi_kin_ddelta = (
            acc * gk_t * sec2 + v * steer * (gk_tt * sec2 + gk_t * 2.0 * t) * sec2
        ) / wheelbase
        d_d_beta_kin_ddelta = dslip_rate_k_dt * sec2 * steer
        A[i, SX, V] = w * cos_dyn + wk * cos_kin + v * dw * (cos_dyn - cos_kin)
        A[i, SY, V] = w * sin_dyn + wk * sin_kin + v * dw * (sin_dyn - sin_kin)
        A[i, SX, PSI] = -v * (w * sin_dyn + wk * sin_kin)
        A[i, SY, PSI] = v * (w * cos_dyn + wk * cos_kin)
        A[i, SX, BETA] = -v * w * sin_dyn
        A[i, SY, BETA] = v * w * cos_dyn
        A[i, SX, DELTA] = -v * wk * sin_kin * slip_rate_k
        A[i, SY, DELTA] = v * wk * cos_kin * slip_rate_k
        B[i, DELTA, 0] = d_steer
        A[i, V, V] = d_acc_dv
        B[i, V, 1] = d_acc_du1
        A[i, PSI, PSI_DOT] = w
        A[i, PSI, DELTA] = wk * d_psi_dot_k_ddelta
        A[i, PSI, V] = wk * gk / wheelbase + dw * (r - psi_dot_k)
        _dynamic_row(
            A, B, i, PSI_DOT, w, psi_delta, psi_beta, psi_r, psi_vd, psi_acc, dvd_dv, d_acc_dv,
            d_acc_du1,
        )  # fmt: skip
        _dynamic_row(
            A, B, i, BETA, w, beta_delta, beta_beta, beta_r, beta_vd, beta_acc, dvd_dv, d_acc_dv,
            d_acc_du1,
        )  # fmt: skip
        P[i, PSI_DOT, 0], P[i, BETA, 0] = w * psi_mu, w * beta_mu
        P[i, PSI_DOT, 1], P[i, BETA, 1] = w * psi_c_sf, w * beta_c_sf
        P[i, PSI_DOT, 2], P[i, BETA, 2] = w * psi_c_sr, w * beta_c_sr
        A[i, PSI_DOT, DELTA] += wk * d_dd_psi_kin_ddelta
        A[i, PSI_DOT, V] += wk * ((d_acc_dv * gk + gk_t * sec2 * steer) / wheelbase) + dw * (
            dd_psi_dyn - dd_psi_kin
        )
        B[i, PSI_DOT, 0] = wk * v * gk_t * sec2 * d_steer / wheelbase
        B[i, PSI_DOT, 1] += wk * gk * d_acc_du1 / wheelbase
        A[i, BETA, DELTA] += wk * d_d_beta_kin_ddelta
        A[i, BETA, V] += dw * (d_beta_dyn - d_beta_kin)
        B[i, BETA, 0] = wk * slip_rate_k * d_steer


if numba is not None:
    _dynamic_row = numba.njit(cache=True, nogil=True)(_dynamic_row)
dynamic_rows = (
    numba.njit(cache=True, nogil=True, error_model="numpy")(_rows) if numba is not None else None
)
"""The compiled :func:`_rows` (None without numba)."""


@lru_cache(maxsize=32)
def kernel_constants(params: VehicleParams) -> np.ndarray:
    """The kernel's constants, each formed as ``single_track._evaluate`` forms it (the same
    Python products, so the same bits); read-only, kept per vehicle."""
    p = params
    g, m, iz, lf, lr, h = p.g, p.m, p.I_z, p.lf, p.lr, p.h
    wheelbase = lf + lr
    k = np.empty(N_CONSTANTS)
    k[[K_M, K_LF, K_LR, K_H, K_WHEELBASE]] = m, lf, lr, h, wheelbase
    k[[K_G_LR, K_G_LF, K_IZ_WHEELBASE]] = g * lr, g * lf, iz * wheelbase
    k[[K_LF2, K_LR2, K_NEG_LF, K_NEG_LF2]] = lf**2, lr**2, -lf, -(lf**2)
    k[K_M_IZ_WHEELBASE] = m / (iz * wheelbase)
    k[[K_DELTA_MIN, K_DELTA_MAX, K_DELTA_DOT_MIN, K_DELTA_DOT_MAX]] = (
        p.delta_min,
        p.delta_max,
        p.delta_dot_min,
        p.delta_dot_max,
    )
    k[[K_NEG_A_MAX, K_V_SWITCH, K_A_MAX_V_SWITCH]] = (
        -p.a_max,
        p.v_switch,
        p.a_max * p.v_switch,
    )
    k[[K_V_MIN, K_V_MAX, K_V_BLEND_LO, K_SPAN]] = (
        p.v_min,
        p.v_max,
        V_BLEND_LO,
        V_BLEND_HI - V_BLEND_LO,
    )
    k.setflags(write=False)
    return k


def jacobians(x, u, theta, params: VehicleParams):
    """``(f, A, B, P)`` of ``single_track.st_jacobians`` for a batch ``x`` (N, 7), ``u`` (N, 2),
    ``theta`` (1 or N, 3) whose speeds are all at least ``V_BLEND_HI``, checked finite."""
    n = x.shape[0]
    f = np.empty((n, NX))
    A, B, P = np.zeros((n, NX, NX)), np.zeros((n, NX, NU)), np.zeros((n, NX, NTHETA))
    dynamic_rows(
        np.ascontiguousarray(x),
        np.ascontiguousarray(u),
        np.ascontiguousarray(theta),
        kernel_constants(params),
        f,
        A,
        B,
        P,
    )
    return f, A, B, P
