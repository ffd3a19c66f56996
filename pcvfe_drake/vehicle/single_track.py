"""The CommonRoad single-track (ST) model, vectorised, with exact Jacobians.

State order (CommonRoad's; used everywhere in this project)::

    x = [sx, sy, delta, v, psi, psi_dot, beta]
         sx, sy   position of the centre of gravity in the world frame [m]
         delta    front wheel steering angle [rad]
         v        speed of the centre of gravity [m/s]
         psi      heading (yaw) [rad]
         psi_dot  yaw rate [rad/s]
         beta     side-slip angle at the centre of gravity [rad]

    u = [steer_rate, accel]   steering rate [rad/s], longitudinal acceleration [m/s^2]

    theta = [mu, C_Sf, C_Sr]  friction coefficient [-], normalised cornering stiffnesses [1/rad]

``st_dynamics`` applies CommonRoad's input constraints (steering rate clipped to its bounds and
zeroed at the angle limits; acceleration clipped to [-a_max, a_max * v_switch / v] above v_switch,
zeroed at the speed limits) and then evaluates:

* the dynamic ST equations of CommonRoad (``vehicle_dynamics_st``) for v >= ``V_BLEND_HI``
  (0.5 m/s); there the result equals the package to rounding;
* a kinematic single-track model for v <= ``V_BLEND_LO`` (0.1 m/s), also used when reversing;
* a C1 blend ``w f_dyn + (1 - w) f_kin`` in between, with ``w`` a cubic smoothstep of v.

The kinematic model uses the kinematic slip angle ``beta_k = atan(lr tan(delta) / L)`` and yaw rate
``psi_dot_k = v cos(beta_k) tan(delta) / L``; its yaw acceleration and slip rate are the exact time
derivatives of these relations (CommonRoad's kinematic branch squares ``tan(delta)^2 lr / L`` in
the slip rate where ``tan(delta) lr / L`` is meant; here it is correct). The dynamic equations are
evaluated at ``max(v, V_BLEND_LO)``, so nothing divides by a speed near zero.

All functions take a single state (shape (7,)) or a batch (shape (N, 7)) and return matching
shapes. Jacobians are analytic (exact almost everywhere; the input constraints are piecewise).
"""

from __future__ import annotations

import math

import numpy as np

from pcvfe_drake.vehicle.params import VehicleParams

SX, SY, DELTA, V, PSI, PSI_DOT, BETA = range(7)
STATE_NAMES = ("sx", "sy", "delta", "v", "psi", "psi_dot", "beta")
STATE_UNITS = ("m", "m", "rad", "m/s", "rad", "rad/s", "rad")
INPUT_NAMES = ("steer_rate", "accel")
INPUT_UNITS = ("rad/s", "m/s^2")
NX, NU, NTHETA = 7, 2, 3

V_BLEND_LO = 0.1
"""Below this speed [m/s] the model is purely kinematic."""
V_BLEND_HI = 0.5
"""Above this speed [m/s] the model is purely the dynamic ST model (CommonRoad's equations)."""


def wrap_angle(angle):
    """Wrap angles [rad] to (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi)


def _as_batch(x, u, theta, params: VehicleParams):
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    single = x.ndim == 1
    x2 = np.atleast_2d(x)
    u2 = np.atleast_2d(u)
    if x2.shape[-1] != NX:
        raise ValueError(f"state must have {NX} entries {STATE_NAMES}, got shape {x.shape}")
    if u2.shape[-1] != NU:
        raise ValueError(f"input must have {NU} entries {INPUT_NAMES}, got shape {u.shape}")
    n = max(x2.shape[0], u2.shape[0])
    x2 = np.broadcast_to(x2, (n, NX))
    u2 = np.broadcast_to(u2, (n, NU))
    th = np.atleast_2d(params.theta if theta is None else np.asarray(theta, dtype=float))
    if th.shape[-1] != NTHETA or th.shape[0] not in (1, n):
        raise ValueError(f"theta must have shape (3,) or ({n}, 3), got {th.shape}")
    return x2, u2, th, single


def _constrained(delta, v, u0, u1, p: VehicleParams, derivatives: bool):
    """Constrained (steer, acc) from 1-D arrays, and their derivatives when asked."""
    steer = np.clip(u0, p.delta_dot_min, p.delta_dot_max)
    pos_limit = p.a_max * p.v_switch / np.maximum(v, p.v_switch)
    acc = np.minimum(np.maximum(u1, -p.a_max), pos_limit)
    # The stops at the steering-angle and speed limits, evaluated only when some state is at a
    # limit (two reductions instead of seven element-wise operations each).
    if delta.min() <= p.delta_min or delta.max() >= p.delta_max:
        steer_stop = ((delta <= p.delta_min) & (u0 <= 0)) | ((delta >= p.delta_max) & (u0 >= 0))
        steer = np.where(steer_stop, 0.0, steer)
    else:
        steer_stop = np.zeros(delta.shape, dtype=bool)
    if v.min() <= p.v_min or v.max() >= p.v_max:
        acc_stop = ((v <= p.v_min) & (u1 <= 0)) | ((v >= p.v_max) & (u1 >= 0))
        acc = np.where(acc_stop, 0.0, acc)
    else:
        acc_stop = np.zeros(v.shape, dtype=bool)
    if not derivatives:
        return steer, acc, None, None, None
    d_steer = np.where(steer_stop | (u0 <= p.delta_dot_min) | (u0 >= p.delta_dot_max), 0.0, 1.0)
    acc_low = ~acc_stop & (u1 <= -p.a_max)
    acc_high = ~acc_stop & ~acc_low & (u1 >= pos_limit)
    d_acc_du1 = np.where(acc_stop | acc_low | acc_high, 0.0, 1.0)
    d_acc_dv = np.where(acc_high & (v > p.v_switch), -pos_limit / np.maximum(v, p.v_switch), 0.0)
    return steer, acc, d_steer, d_acc_du1, d_acc_dv


def constrain_inputs(x, u, params: VehicleParams):
    """CommonRoad's input constraints, vectorised.

    Returns ``(u_eff, d_steer_du0, d_acc_du1, d_acc_dv)``: the constrained inputs (N, 2) and the
    derivatives of the constrained steering rate w.r.t. the command, and of the constrained
    acceleration w.r.t. the command and w.r.t. the speed (each (N,)).
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    u = np.atleast_2d(np.asarray(u, dtype=float))
    steer, acc, d_steer, d_acc_du1, d_acc_dv = _constrained(
        x[:, DELTA], x[:, V], u[:, 0], u[:, 1], params, derivatives=True
    )
    return np.stack([steer, acc], axis=1), d_steer, d_acc_du1, d_acc_dv


def _blend_weight(v):
    """Cubic smoothstep weight of the dynamic model and its derivative w.r.t. v."""
    span = V_BLEND_HI - V_BLEND_LO
    s = np.clip((v - V_BLEND_LO) / span, 0.0, 1.0)
    w = s * s * (3.0 - 2.0 * s)
    dw = 6.0 * s * (1.0 - s) / span
    return w, dw


def _evaluate(x, u, params: VehicleParams, theta, with_jacobians: bool):
    """Core evaluation on batches; returns f (N,7) and optionally A, B, P."""
    p = params
    g, m, iz, lf, lr, h = p.g, p.m, p.I_z, p.lf, p.lr, p.h
    wheelbase = lf + lr
    n = x.shape[0]
    xt = np.ascontiguousarray(x.T)  # one row per state entry: contiguous element-wise ops
    delta, v, psi, r, beta = xt[DELTA], xt[V], xt[PSI], xt[PSI_DOT], xt[BETA]
    ut = np.ascontiguousarray(u.T)
    steer, acc, d_steer, d_acc_du1, d_acc_dv = _constrained(
        delta, v, ut[0], ut[1], p, with_jacobians
    )
    mu, c_sf, c_sr = theta[:, 0], theta[:, 1], theta[:, 2]

    # Dynamic ST model, evaluated at a speed bounded away from zero.
    vd = np.maximum(v, V_BLEND_LO)
    gf = g * lr - acc * h
    gr = g * lf + acc * h
    ff = c_sf * gf
    fr = c_sr * gr
    k_yaw = mu * m / (iz * wheelbase)
    yaw_sum = lf**2 * ff + lr**2 * fr
    moment = lr * fr - lf * ff
    r_v = r / vd
    dd_psi_dyn = k_yaw * ((lf * ff) * delta + moment * beta - yaw_sum * r_v)
    k_slip = mu / (vd * wheelbase)
    slip_sum = ff * delta - (fr + ff) * beta + moment * r_v
    d_beta_dyn = k_slip * slip_sum - r
    cos_dyn = np.cos(psi + beta)
    sin_dyn = np.sin(psi + beta)

    # Kinematic single-track model at the centre of gravity; skipped when every speed is in the
    # purely dynamic range (the common case for fitting and control).
    kinematic = bool(np.any(v < V_BLEND_HI))
    if kinematic or with_jacobians:
        w, dw = _blend_weight(v)
    if kinematic:
        c = lr / wheelbase
        t = np.tan(delta)
        sec2 = 1.0 + t * t
        q = 1.0 + c * c * t * t
        beta_k = np.arctan(c * t)
        gk = t / np.sqrt(q)  # cos(beta_k) tan(delta)
        gk_t = q**-1.5  # d gk / d tan(delta)
        psi_dot_k = v * gk / wheelbase
        slip_rate_k = c * sec2 / q  # d beta_k / d delta
        d_beta_kin = slip_rate_k * steer
        dd_psi_kin = (acc * gk + v * gk_t * sec2 * steer) / wheelbase
        cos_kin = np.cos(psi + beta_k)
        sin_kin = np.sin(psi + beta_k)

    ft = np.empty((NX, n))  # filled row by row (contiguous), returned transposed
    ft[DELTA] = steer
    ft[V] = acc
    if kinematic:
        wk = 1.0 - w
        ft[SX] = v * (w * cos_dyn + wk * cos_kin)
        ft[SY] = v * (w * sin_dyn + wk * sin_kin)
        ft[PSI] = w * r + wk * psi_dot_k
        ft[PSI_DOT] = w * dd_psi_dyn + wk * dd_psi_kin
        ft[BETA] = w * d_beta_dyn + wk * d_beta_kin
    else:
        np.multiply(v, cos_dyn, out=ft[SX])
        np.multiply(v, sin_dyn, out=ft[SY])
        ft[PSI] = r
        ft[PSI_DOT] = dd_psi_dyn
        ft[BETA] = d_beta_dyn
    f = ft.T
    if not with_jacobians:
        return f, None, None, None

    dvd_dv = (v > V_BLEND_LO).astype(float)
    A = np.zeros((n, NX, NX))
    B = np.zeros((n, NX, NU))
    P = np.zeros((n, NX, NTHETA))

    # --- derivatives of the dynamic parts
    dpsi_dd = {
        "delta": k_yaw * lf * ff,
        "beta": k_yaw * moment,
        "r": -k_yaw * yaw_sum / vd,
        "vd": k_yaw * yaw_sum * r / vd**2,
        "acc": k_yaw
        * (
            -lf * c_sf * h * delta
            + (lr * c_sr * h + lf * c_sf * h) * beta
            - (-(lf**2) * c_sf * h + lr**2 * c_sr * h) * r / vd
        ),
        "mu": m / (iz * wheelbase) * (lf * ff * delta + moment * beta - yaw_sum * r / vd),
        "c_sf": k_yaw * (lf * gf * delta - lf * gf * beta - lf**2 * gf * r / vd),
        "c_sr": k_yaw * (lr * gr * beta - lr**2 * gr * r / vd),
    }
    dbeta_d = {
        "delta": k_slip * ff,
        "beta": -k_slip * (fr + ff),
        "r": k_slip * moment / vd - 1.0,
        "vd": -k_slip / vd * slip_sum - k_slip * moment * r / vd**2,
        "acc": k_slip
        * (
            -c_sf * h * delta
            - (c_sr * h - c_sf * h) * beta
            + (lr * c_sr * h + lf * c_sf * h) * r / vd
        ),
        "mu": slip_sum / (vd * wheelbase),
        "c_sf": k_slip * (gf * delta - gf * beta - lf * gf * r / vd),
        "c_sr": k_slip * (-gr * beta + lr * gr * r / vd),
    }

    if not kinematic:
        # w = 1 and dw = 0 everywhere: the kinematic terms below vanish; give them neutral values.
        zeros = np.zeros(n)
        c, t, sec2, q, gk, gk_t = 0.0, zeros, zeros, np.ones(n), zeros, zeros
        slip_rate_k = psi_dot_k = d_beta_kin = dd_psi_kin = zeros
        cos_kin = sin_kin = zeros
    wk = 1.0 - w

    # --- derivatives of the kinematic parts w.r.t. delta
    dslip_rate_k_dt = 2.0 * c * t * (1.0 - c * c) / q**2
    gk_tt = -3.0 * c * c * t * q**-2.5
    dbeta_k_ddelta = slip_rate_k
    d_psi_dot_k_ddelta = v * gk_t * sec2 / wheelbase
    d_dd_psi_kin_ddelta = (
        acc * gk_t * sec2 + v * steer * (gk_tt * sec2 + gk_t * 2.0 * t) * sec2
    ) / wheelbase
    d_d_beta_kin_ddelta = dslip_rate_k_dt * sec2 * steer

    # Position rows.
    A[:, SX, V] = w * cos_dyn + wk * cos_kin + v * dw * (cos_dyn - cos_kin)
    A[:, SY, V] = w * sin_dyn + wk * sin_kin + v * dw * (sin_dyn - sin_kin)
    A[:, SX, PSI] = -v * (w * sin_dyn + wk * sin_kin)
    A[:, SY, PSI] = v * (w * cos_dyn + wk * cos_kin)
    A[:, SX, BETA] = -v * w * sin_dyn
    A[:, SY, BETA] = v * w * cos_dyn
    A[:, SX, DELTA] = -v * wk * sin_kin * dbeta_k_ddelta
    A[:, SY, DELTA] = v * wk * cos_kin * dbeta_k_ddelta

    # Steering and speed rows.
    B[:, DELTA, 0] = d_steer
    A[:, V, V] = d_acc_dv
    B[:, V, 1] = d_acc_du1

    # Heading row.
    A[:, PSI, PSI_DOT] = w
    A[:, PSI, DELTA] = wk * d_psi_dot_k_ddelta
    A[:, PSI, V] = wk * gk / wheelbase + dw * (r - psi_dot_k)

    # Yaw-acceleration and slip rows: dynamic part.
    for row, d in ((PSI_DOT, dpsi_dd), (BETA, dbeta_d)):
        A[:, row, DELTA] = w * d["delta"]
        A[:, row, BETA] = w * d["beta"]
        A[:, row, PSI_DOT] = w * d["r"]
        A[:, row, V] = w * (d["vd"] * dvd_dv + d["acc"] * d_acc_dv)
        B[:, row, 1] = w * d["acc"] * d_acc_du1
        P[:, row, 0] = w * d["mu"]
        P[:, row, 1] = w * d["c_sf"]
        P[:, row, 2] = w * d["c_sr"]

    # Kinematic part and blend-weight terms.
    A[:, PSI_DOT, DELTA] += wk * d_dd_psi_kin_ddelta
    A[:, PSI_DOT, V] += wk * ((d_acc_dv * gk + gk_t * sec2 * steer) / wheelbase) + dw * (
        dd_psi_dyn - dd_psi_kin
    )
    B[:, PSI_DOT, 0] = wk * v * gk_t * sec2 * d_steer / wheelbase
    B[:, PSI_DOT, 1] += wk * gk * d_acc_du1 / wheelbase
    A[:, BETA, DELTA] += wk * d_d_beta_kin_ddelta
    A[:, BETA, V] += dw * (d_beta_dyn - d_beta_kin)
    B[:, BETA, 0] = wk * slip_rate_k * d_steer
    return f, A, B, P


def _check_finite(x, u, theta):
    for name, arr in (("state", x), ("input", u), ("theta", theta)):
        # A sum is finite when every entry is (cheaper than isfinite + all); an overflowing sum
        # of finite values falls through to the exact check.
        if np.isfinite(np.add.reduce(arr, axis=None)) or np.all(np.isfinite(arr)):
            continue
        bad = np.argwhere(~np.isfinite(np.atleast_2d(arr)))[0]
        raise ValueError(
            f"st_dynamics: non-finite {name} at row {bad[0]}, entry {bad[1]}: "
            f"{np.atleast_2d(arr)[bad[0], bad[1]]!r}"
        )


_BLOCK = 4096
"""Batches are evaluated in blocks of this many states so the temporaries stay in cache."""


def _in_blocks(x2, u2, th, params, with_jacobians):
    n = x2.shape[0]
    if n <= _BLOCK:
        return _evaluate(x2, u2, params, th, with_jacobians)
    outputs = [np.empty((n, NX))]
    if with_jacobians:
        outputs += [np.empty((n, NX, NX)), np.empty((n, NX, NU)), np.empty((n, NX, NTHETA))]
    for start in range(0, n, _BLOCK):
        block = slice(start, start + _BLOCK)
        th_block = th if th.shape[0] == 1 else th[block]
        parts = _evaluate(x2[block], u2[block], params, th_block, with_jacobians)
        for out, part in zip(outputs, parts, strict=False):
            out[block] = part
    return tuple(outputs) + (None,) * (4 - len(outputs))


def _st_dynamics_single(x, u, p: VehicleParams) -> np.ndarray:
    """Scalar evaluation of one state in the purely dynamic range (v >= V_BLEND_HI).

    The same equations as ``_evaluate`` written with ``math`` for the per-step cost of a
    simulated plant (a numpy call per entry would cost ~100x more for one state).
    """
    sx_, sy_, delta, v, psi, r, beta = (float(e) for e in x)
    u0, u1 = float(u[0]), float(u[1])
    if (delta <= p.delta_min and u0 <= 0) or (delta >= p.delta_max and u0 >= 0):
        steer = 0.0
    else:
        steer = min(max(u0, p.delta_dot_min), p.delta_dot_max)
    pos_limit = p.a_max * p.v_switch / v if v > p.v_switch else p.a_max
    if (v <= p.v_min and u1 <= 0) or (v >= p.v_max and u1 >= 0):
        acc = 0.0
    else:
        acc = min(max(u1, -p.a_max), pos_limit)
    g, lf, lr, h = p.g, p.lf, p.lr, p.h
    wheelbase = lf + lr
    ff = p.C_Sf * (g * lr - acc * h)
    fr = p.C_Sr * (g * lf + acc * h)
    moment = lr * fr - lf * ff
    dd_psi = (
        p.mu
        * p.m
        / (p.I_z * wheelbase)
        * (lf * ff * delta + moment * beta - (lf * lf * ff + lr * lr * fr) * r / v)
    )
    d_beta = p.mu / (v * wheelbase) * (ff * delta - (fr + ff) * beta + moment * r / v) - r
    return np.array(
        [v * math.cos(psi + beta), v * math.sin(psi + beta), steer, acc, r, dd_psi, d_beta]
    )


def st_dynamics(x, u, params: VehicleParams, theta=None) -> np.ndarray:
    """Time derivative of the ST state (see module docstring for orders and units).

    Args:
        x: state(s), shape (7,) or (N, 7).
        u: input(s) [steer_rate, accel], shape (2,) or (N, 2).
        params: vehicle parameters.
        theta: optional [mu, C_Sf, C_Sr] overriding ``params``, shape (3,) or (N, 3).
    Raises:
        ValueError: on non-finite inputs or wrong shapes.
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    if (
        theta is None
        and x.shape == (NX,)
        and u.shape == (NU,)
        and x[V] >= V_BLEND_HI
        and all(math.isfinite(e) for e in x)
        and all(math.isfinite(e) for e in u)
    ):
        return _st_dynamics_single(x, u, params)
    x2, u2, th, single = _as_batch(x, u, theta, params)
    _check_finite(x2, u2, th)
    f = _in_blocks(x2, u2, th, params, with_jacobians=False)[0]
    return f[0] if single else f


def st_jacobians(x, u, params: VehicleParams, theta=None):
    """``(xdot, A, B, P)``: the derivative and its exact Jacobians.

    ``A = d xdot / d x`` (N, 7, 7), ``B = d xdot / d u`` (N, 7, 2) and
    ``P = d xdot / d theta`` (N, 7, 3) with theta = [mu, C_Sf, C_Sr]. Single states give
    unbatched shapes.
    """
    x2, u2, th, single = _as_batch(x, u, theta, params)
    _check_finite(x2, u2, th)
    from pcvfe_drake.vehicle import single_track_kernel as kernel  # it imports this module

    if kernel.dynamic_rows is not None and x2.shape[0] and x2[:, V].min() >= V_BLEND_HI:
        f, A, B, P = kernel.jacobians(x2, u2, th, params)
    else:
        f, A, B, P = _in_blocks(x2, u2, th, params, with_jacobians=True)
    if single:
        return f[0], A[0], B[0], P[0]
    return f, A, B, P


def rk4_step(x, u, params: VehicleParams, dt: float, theta=None, jacobians: bool = False):
    """One classical Runge-Kutta step of duration ``dt`` [s] with the input held.

    Returns ``x_next``, or with ``jacobians=True`` ``(x_next, Ad, Bd, Pd)``: the exact derivatives
    of the RK4 map w.r.t. the state, the input and theta.
    """
    x2, u2, th, single = _as_batch(x, u, theta, params)
    _check_finite(x2, u2, th)
    if not jacobians:
        k1 = _evaluate(x2, u2, params, th, False)[0]
        k2 = _evaluate(x2 + 0.5 * dt * k1, u2, params, th, False)[0]
        k3 = _evaluate(x2 + 0.5 * dt * k2, u2, params, th, False)[0]
        k4 = _evaluate(x2 + dt * k3, u2, params, th, False)[0]
        xn = x2 + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return xn[0] if single else xn

    eye = np.eye(NX)
    k1, a1, b1, p1 = _evaluate(x2, u2, params, th, True)
    k2, a2, b2, p2 = _evaluate(x2 + 0.5 * dt * k1, u2, params, th, True)
    k3, a3, b3, p3 = _evaluate(x2 + 0.5 * dt * k2, u2, params, th, True)
    k4, a4, b4, p4 = _evaluate(x2 + dt * k3, u2, params, th, True)
    xn = x2 + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    # Chain rule through the stages: dk_i = A_i (d(stage input)) + (B_i or P_i).
    dk1x = a1
    dk2x = a2 @ (eye + 0.5 * dt * dk1x)
    dk3x = a3 @ (eye + 0.5 * dt * dk2x)
    dk4x = a4 @ (eye + dt * dk3x)
    ad = eye + dt / 6.0 * (dk1x + 2.0 * dk2x + 2.0 * dk3x + dk4x)

    def through_stages(d1, d2, d3, d4):
        s1 = d1
        s2 = d2 + 0.5 * dt * (a2 @ s1)
        s3 = d3 + 0.5 * dt * (a3 @ s2)
        s4 = d4 + dt * (a4 @ s3)
        return dt / 6.0 * (s1 + 2.0 * s2 + 2.0 * s3 + s4)

    bd = through_stages(b1, b2, b3, b4)
    pd = through_stages(p1, p2, p3, p4)
    if single:
        return xn[0], ad[0], bd[0], pd[0]
    return xn, ad, bd, pd


def rollout(x0, U, params: VehicleParams, dt: float, theta=None, sensitivities: bool = False):
    """Roll the ST model out from ``x0`` with the input sequence ``U`` (zero-order hold, RK4).

    Args:
        x0: initial states, shape (B, 7) (or (7,) for one rollout).
        U: inputs, shape (B, H, 2) (or (H, 2)).
        params: vehicle parameters.
        dt: step [s].
        theta: optional [mu, C_Sf, C_Sr] override, (3,) or (B, 3).
        sensitivities: also return ``S = dX / dtheta`` of shape (B, H+1, 7, 3).
    Returns:
        ``X`` of shape (B, H+1, 7) with ``X[:, 0] = x0``, and ``S`` when asked.
    """
    x0 = np.asarray(x0, dtype=float)
    U = np.asarray(U, dtype=float)
    single = x0.ndim == 1
    x = np.atleast_2d(x0)
    U3 = U[None] if U.ndim == 2 else U
    if U3.ndim != 3 or U3.shape[-1] != NU:
        raise ValueError(f"U must have shape (B, H, {NU}), got {U.shape}")
    nb, horizon = U3.shape[0], U3.shape[1]
    if x.shape[0] != nb:
        raise ValueError(f"x0 has {x.shape[0]} rows but U has {nb} sequences")
    th = None if theta is None else np.broadcast_to(np.atleast_2d(theta), (nb, NTHETA))
    X = np.empty((nb, horizon + 1, NX))
    X[:, 0] = x
    S = np.zeros((nb, horizon + 1, NX, NTHETA)) if sensitivities else None
    for k in range(horizon):
        if sensitivities:
            xn, ad, _, pd = rk4_step(X[:, k], U3[:, k], params, dt, th, jacobians=True)
            S[:, k + 1] = ad @ S[:, k] + pd
        else:
            xn = rk4_step(X[:, k], U3[:, k], params, dt, th)
        X[:, k + 1] = xn
    if single:
        return (X[0], S[0]) if sensitivities else X[0]
    return (X, S) if sensitivities else X
