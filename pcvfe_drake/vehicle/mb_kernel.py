"""The multi-body truth's derivative, compiled (numba): CommonRoad's MB equations on scalars.

:class:`pcvfe_drake.vehicle.mb_truth.MbTruth` integrates CommonRoad's multi-body model
(``vehiclemodels.vehicle_dynamics_mb``, 29 states; the state order is the package's, listed in
``mb_truth``). The package evaluates it in plain Python, about a thousand floating-point
operations per call behind attribute look-ups and list appends, and a simulated second asks
for a couple of thousand calls. :func:`mb_derivative` is the same derivative written on
scalars and compiled, so that the plant costs its arithmetic only. The package stays the
reference: ``tests/vehicle/test_mb_kernel.py`` checks that the two agree bit for bit.

Bit for bit means the same operations in the same order: each expression keeps the package's
grouping (Python evaluates ``a * b * c`` as ``(a * b) * c``; a sum over several lines is one
left-to-right sum), the transcendental functions are the C library's, as Python's ``math``
calls them, and a square ``y ** 2`` is the C library's ``pow(y, 2.0)``
(:func:`_libm_pow`): CPython computes a float power with ``pow``, which differs from
``y * y`` in the last place for a few inputs in ten thousand, and LLVM would otherwise replace
``pow(y, 2.0)`` by that product.

Parameters are one flat float64 vector (:func:`mb_parameter_vector`, fields in the order of
:data:`MB_PARAMETER_FIELDS`), built once per parameter set, so a call converts nothing.

Where the package divides by zero (a wheel's ground speed <= 0 with ``|v_x| >= 0.1`` m/s, and
the measure-zero cases of a slip angle's denominator or a tire load of exactly 0) it raises
``ZeroDivisionError``; :func:`mb_derivative` returns a nonzero code instead (:data:`SINGULAR`)
and leaves NaN in its output, and ``MbTruth.rhs`` turns the code into ``MbSingularity``.
"""

from __future__ import annotations

import math

import numpy as np

from pcvfe_drake.models.compiled_kernel import jit

try:  # numba is a dependency; without it the kernel runs as plain Python (slowly)
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover - exercised only without numba
    intrinsic = None

G_MPS2 = 9.81
"""Gravity [m/s^2], the package's constant."""
KINEMATIC_BELOW_MPS = 0.1
"""Below this ``|v_x|`` [m/s] the package uses kinematic equations (no slip, no division)."""

MB_PARAMETER_FIELDS = (
    # geometry [m]: CG to front/rear axle, track widths, wheel radius, heights of the sprung
    # mass's CG and of the front/rear roll axes
    "a", "b", "T_f", "T_r", "R_w", "h_s", "h_raf", "h_rar",
    # masses [kg] (total, sprung, front/rear unsprung); inertias [kg m^2] (yaw, sprung
    # roll-yaw product, sprung roll, sprung pitch, front/rear unsprung roll, wheel spin)
    "m", "m_s", "m_uf", "m_ur", "I_z", "I_xz_s", "I_Phi_s", "I_y_s", "I_uf", "I_ur", "I_y_w",
    # suspension: spring [N/m] and damper [N s/m] front/rear, anti-roll bars [N m/rad],
    # compliant joint spring [N/m] and damper [N s/m], tire vertical stiffness [N/m], tire
    # lateral compliance [m/N], camber per suspension travel [rad/m] and [rad/m^2]
    "K_sf", "K_sdf", "K_sr", "K_sdr", "K_tsf", "K_tsr", "K_ras", "K_rad", "K_zt", "K_lt", "D_f",
    "E_f", "D_r", "E_r",
    # torque split to the front axle [-]: braking, engine
    "T_sb", "T_se",
    # steering limits: angle [rad], rate [rad/s]
    "steering.min", "steering.max", "steering.v_min", "steering.v_max",
    # longitudinal limits: speed [m/s], speed above which the power limits acceleration
    # [m/s], acceleration [m/s^2]
    "longitudinal.v_min", "longitudinal.v_max", "longitudinal.v_switch", "longitudinal.a_max",
    # Pacejka magic formula (dimensionless coefficients; the package's tire_model):
    # longitudinal pure slip, longitudinal combined slip
    "tire.p_cx1", "tire.p_dx1", "tire.p_dx3", "tire.p_ex1", "tire.p_kx1", "tire.p_hx1",
    "tire.p_vx1", "tire.r_bx1", "tire.r_bx2", "tire.r_cx1", "tire.r_ex1", "tire.r_hx1",
    # lateral pure slip, lateral combined slip
    "tire.p_cy1", "tire.p_dy1", "tire.p_dy3", "tire.p_ey1", "tire.p_ky1", "tire.p_hy1",
    "tire.p_hy3", "tire.p_vy1", "tire.p_vy3", "tire.r_by1", "tire.r_by2", "tire.r_by3",
    "tire.r_cy1", "tire.r_ey1", "tire.r_hy1", "tire.r_vy1", "tire.r_vy3", "tire.r_vy4",
    "tire.r_vy5", "tire.r_vy6",
)  # fmt: skip
"""The parameter vector's fields in order: attribute paths in a ``vehiclemodels`` parameter
set (names and units as in CommonRoad's vehicle model documentation)."""
(A, B, T_F, T_R, R_W, H_S, H_RAF, H_RAR,
 M, M_S, M_UF, M_UR, I_Z, I_XZ_S, I_PHI_S, I_Y_S, I_UF, I_UR, I_Y_W,
 K_SF, K_SDF, K_SR, K_SDR, K_TSF, K_TSR, K_RAS, K_RAD, K_ZT, K_LT, D_F, E_F, D_R, E_R,
 T_SB, T_SE,
 STEER_MIN, STEER_MAX, STEER_RATE_MIN, STEER_RATE_MAX,
 V_MIN, V_MAX, V_SWITCH, A_MAX,
 P_CX1, P_DX1, P_DX3, P_EX1, P_KX1, P_HX1, P_VX1, R_BX1, R_BX2, R_CX1, R_EX1, R_HX1,
 P_CY1, P_DY1, P_DY3, P_EY1, P_KY1, P_HY1, P_HY3, P_VY1, P_VY3,
 R_BY1, R_BY2, R_BY3, R_CY1, R_EY1, R_HY1, R_VY1, R_VY3, R_VY4, R_VY5, R_VY6,
 ) = range(len(MB_PARAMETER_FIELDS))  # fmt: skip

REGULAR = 0
""":func:`mb_derivative`'s code for a derivative it computed."""
WHEEL_AT_REST_OVER_GROUND, SLIP_ANGLE_DIVISION, ZERO_TIRE_LOAD = 1, 2, 3
"""Codes where the package divides by zero: a wheel's ground speed <= 0 (its longitudinal
slip), the denominator ``v_x +- T/2 psi_dot`` of a slip angle exactly 0, a tire's vertical
load exactly 0 (its slip stiffness over its peak force)."""
SINGULAR = {
    WHEEL_AT_REST_OVER_GROUND: "a wheel's ground speed is <= 0 (its longitudinal slip)",
    SLIP_ANGLE_DIVISION: "a wheel's speed along the body, v_x +- T/2 psi_dot, is 0 (its slip "
    "angle)",
    ZERO_TIRE_LOAD: "a tire's vertical load is 0 (its slip stiffness over its peak force)",
}
"""What each nonzero code of :func:`mb_derivative` divides by zero."""


def mb_parameter_vector(p) -> np.ndarray:
    """The flat parameter vector (float64, order :data:`MB_PARAMETER_FIELDS`) of a
    ``vehiclemodels`` parameter set ``p`` (``p.tire``, ``p.steering``, ``p.longitudinal``
    included). Build it once per parameter set: it is a copy, later changes to ``p`` are not
    seen."""
    values = []
    for field in MB_PARAMETER_FIELDS:
        obj = p
        for name in field.split("."):
            if not hasattr(obj, name):
                raise ValueError(f"multi-body parameters: the parameter set has no {field!r}")
            obj = getattr(obj, name)
        try:
            value = float(obj)
        except (TypeError, ValueError):
            raise ValueError(f"multi-body parameters: {field} = {obj!r} is not a number") from None
        if not math.isfinite(value):
            raise ValueError(f"multi-body parameters: {field} = {value!r} is not finite")
        values.append(value)
    return np.array(values, dtype=np.float64)


# ---------------------------------------------------------------------------- the C library's pow
if intrinsic is not None:

    @intrinsic
    def _libm_pow(typingctx, base, exponent):
        """``pow(base, exponent)`` of the C library, called as a plain function: the
        declaration is marked ``nobuiltin``, so that LLVM keeps the call (it would turn
        ``pow(y, 2.0)`` into ``y * y``, which is not what CPython's ``y ** 2`` computes)."""
        sig = types.float64(types.float64, types.float64)

        def codegen(context, builder, signature, args):
            module = builder.module
            fn = module.globals.get("pow")
            if fn is None:
                fnty = ir.FunctionType(ir.DoubleType(), [ir.DoubleType(), ir.DoubleType()])
                fn = ir.Function(module, fnty, name="pow")
            fn.attributes.add("nobuiltin")
            return builder.call(fn, args)

        return sig, codegen

else:  # pragma: no cover - exercised only without numba

    def _libm_pow(base, exponent):
        """CPython's float power: the C library's ``pow``."""
        return base**exponent


# ---------------------------------------------------------------------------- input constraints
@jit(inline="always")
def _steering_rate(delta, rate, pv):
    """The package's ``steering_constraints``: the steering rate [rad/s] at steering angle
    ``delta`` [rad], 0 against an angle limit, clipped to the rate limits."""
    if (delta <= pv[STEER_MIN] and rate <= 0) or (delta >= pv[STEER_MAX] and rate >= 0):
        return 0.0
    if rate <= pv[STEER_RATE_MIN]:
        return pv[STEER_RATE_MIN]
    if rate >= pv[STEER_RATE_MAX]:
        return pv[STEER_RATE_MAX]
    return rate


@jit(inline="always")
def _acceleration(v, acc, pv):
    """The package's ``acceleration_constraints``: the acceleration [m/s^2] at speed ``v``
    [m/s], 0 against a speed limit, at least ``-a_max``, at most ``a_max`` (``a_max v_switch /
    v`` above ``v_switch``: a power limit)."""
    if v > pv[V_SWITCH]:
        pos_limit = pv[A_MAX] * pv[V_SWITCH] / v
    else:
        pos_limit = pv[A_MAX]
    if (v <= pv[V_MIN] and acc <= 0) or (v >= pv[V_MAX] and acc >= 0):
        return 0.0
    if acc <= -pv[A_MAX]:
        return -pv[A_MAX]
    if acc >= pos_limit:
        return pos_limit
    return acc


# ---------------------------------------------------------------------------- the tire
@jit(inline="always")
def _sign(y):
    """The package's ``sign``: 1, -1, or 0 (also for NaN), as a float."""
    if y > 0:
        return 1.0
    if y < 0:
        return -1.0
    return 0.0


@jit(inline="always")
def _unsprung_roll_moment(F_sl, F_sr, T, F_ra, h_ra, R_w, F_zl, F_zr, F_yl, F_yr, K_lt, phi):
    """An axle's unsprung roll moment [N m] from its suspension forces ``F_sl``, ``F_sr`` [N],
    track ``T`` [m], anti-roll force ``F_ra`` [N] at height ``h_ra`` [m], the tyres' loads and
    lateral forces [N] and the axle's roll ``phi`` [rad], without the term of the axle's
    lateral force, which the caller subtracts (the package's order of operations)."""
    return (
        0.5 * F_sr * T
        - 0.5 * F_sl * T
        - F_ra * (h_ra - R_w)
        + F_zl * (R_w * math.sin(phi) + 0.5 * T * math.cos(phi) - K_lt * F_yl)
        - F_zr * (-R_w * math.sin(phi) + 0.5 * T * math.cos(phi) + K_lt * F_yr)
    )


@jit(inline="always")
def _shape(c, d, e, k, x):
    """The magic formula's ``C atan(B x - E (B x - atan(B x)))`` at slip ``x`` with the
    stiffness factor ``B = k / (C D)``, and the denominator ``C D`` (B NaN where it is 0: the
    package divides by zero there, which uncompiled Python would raise)."""
    den = c * d
    b = k / den if den != 0.0 else math.nan
    bx = b * x
    return c * math.atan(bx - e * (bx - math.atan(bx))), den


@jit(inline="always")
def _pure_longitudinal(slip, gamma, fz, pv):
    """Longitudinal force [N] at pure slip (the package's ``formula_longitudinal``): slip
    ``slip`` [-] (the package negates it), camber ``gamma`` [rad], vertical load ``fz`` [N].
    As in the package, the vertical shift ``S_vx`` sits inside the sine. Also returns the
    denominator ``C_x D_x`` of the stiffness factor (0 where the package divides by zero)."""
    kappa = -slip
    s_hx = pv[P_HX1]
    s_vx = fz * pv[P_VX1]
    kappa_x = kappa + s_hx
    mu_x = pv[P_DX1] * (1.0 - pv[P_DX3] * _libm_pow(gamma, 2.0))
    d_x = mu_x * fz
    shape, den = _shape(pv[P_CX1], d_x, pv[P_EX1], fz * pv[P_KX1], kappa_x)
    return d_x * math.sin(shape + s_vx), den


@jit(inline="always")
def _pure_lateral(alpha, gamma, fz, pv):
    """Lateral force [N] at pure slip and the lateral friction ``mu_y`` [-] (the package's
    ``formula_lateral``): slip angle ``alpha`` [rad], camber ``gamma`` [rad], load ``fz``
    [N]; and the denominator ``C_y D_y`` of the stiffness factor."""
    sg = _sign(gamma)
    s_hy = sg * (pv[P_HY1] + pv[P_HY3] * math.fabs(gamma))
    s_vy = sg * fz * (pv[P_VY1] + pv[P_VY3] * math.fabs(gamma))
    alpha_y = alpha + s_hy
    mu_y = pv[P_DY1] * (1.0 - pv[P_DY3] * _libm_pow(gamma, 2.0))
    d_y = mu_y * fz
    shape, den = _shape(pv[P_CY1], d_y, pv[P_EY1], fz * pv[P_KY1], alpha_y)
    return d_y * math.sin(shape) + s_vy, mu_y, den


@jit(inline="always")
def _combined_longitudinal(slip, alpha, f0_x, pv):
    """Longitudinal force [N] at combined slip (``formula_longitudinal_comb``) from the
    pure-slip force ``f0_x`` [N]: weighted down by the slip angle ``alpha`` [rad]."""
    s_h = pv[R_HX1]
    alpha_s = alpha + s_h
    b = pv[R_BX1] * math.cos(math.atan(pv[R_BX2] * slip))
    c = pv[R_CX1]
    e = pv[R_EX1]
    d = f0_x / (math.cos(c * math.atan(b * s_h - e * (b * s_h - math.atan(b * s_h)))))
    return d * math.cos(c * math.atan(b * alpha_s - e * (b * alpha_s - math.atan(b * alpha_s))))


@jit(inline="always")
def _combined_lateral(slip, alpha, gamma, mu_y, fz, f0_y, pv):
    """Lateral force [N] at combined slip (``formula_lateral_comb``) from the pure-slip force
    ``f0_y`` [N]: weighted down by the longitudinal slip ``slip`` [-], plus the slip-induced
    side force."""
    s_h = pv[R_HY1]
    kappa_s = slip + s_h
    b = pv[R_BY1] * math.cos(math.atan(pv[R_BY2] * (alpha - pv[R_BY3])))
    c = pv[R_CY1]
    e = pv[R_EY1]
    d = f0_y / (math.cos(c * math.atan(b * s_h - e * (b * s_h - math.atan(b * s_h)))))
    d_v = mu_y * fz * (pv[R_VY1] + pv[R_VY3] * gamma) * math.cos(math.atan(pv[R_VY4] * alpha))
    s_v = d_v * math.sin(pv[R_VY5] * math.atan(pv[R_VY6] * slip))
    return (
        d * math.cos(c * math.atan(b * kappa_s - e * (b * kappa_s - math.atan(b * kappa_s)))) + s_v
    )


# ---------------------------------------------------------------------------- the derivative
@jit(inline="always")
def wheel_ground_speeds(x, a, T_f, T_r):
    """The four wheels' ground speeds [m/s] (left front, right front, left rear, right rear)
    along each wheel's heading at MB state ``x``, with the CG-to-front-axle distance ``a`` and
    the track widths ``T_f``, ``T_r`` [m]: what the package divides the longitudinal slips by,
    after setting a negative one to 0 (the package's formulas)."""
    cos_d, sin_d = math.cos(x[2]), math.sin(x[2])
    return (
        (x[3] + 0.5 * T_f * x[5]) * cos_d + (x[10] + a * x[5]) * sin_d,
        (x[3] - 0.5 * T_f * x[5]) * cos_d + (x[10] + a * x[5]) * sin_d,
        x[3] + 0.5 * T_r * x[5],
        x[3] - 0.5 * T_r * x[5],
    )


@jit(inline="always")
def _suspension(static, z, dz, stiffness, damping, roll):
    """One corner's suspension force [N]: its static load, less the spring on the deflection
    ``z`` [m] and the damper on its rate ``dz`` [m/s], plus the anti-roll term ``roll``."""
    return static - z * stiffness - dz * damping + roll


@jit
def mb_derivative(x, steer_rate, accel, pv, out):
    """The multi-body derivative (29,) into ``out`` at state ``x`` (29,) (the package's
    order), input ``[steer_rate rad/s, accel m/s^2]`` and parameter vector ``pv``
    (:func:`mb_parameter_vector`); returns :data:`REGULAR` (0), or a code of :data:`SINGULAR`
    where the package divides by zero (``out`` is then NaN).

    Wheel speeds ``x[23:27]`` enter as ``max(omega, 0)`` (``MbTruth.rhs``'s clamp; ``x`` is
    not changed). After that clamp the package's own rule (a negative wheel speed gets the
    derivative 0) never applies and is left out.
    """
    g = G_MPS2
    a, b, T_f, T_r, R_w = pv[A], pv[B], pv[T_F], pv[T_R], pv[R_W]
    h_s, h_raf, h_rar = pv[H_S], pv[H_RAF], pv[H_RAR]
    m, m_s, m_uf, m_ur = pv[M], pv[M_S], pv[M_UF], pv[M_UR]
    I_z, I_xz_s, I_Phi_s, I_y_s = pv[I_Z], pv[I_XZ_S], pv[I_PHI_S], pv[I_Y_S]
    I_uf, I_ur, I_y_w = pv[I_UF], pv[I_UR], pv[I_Y_W]
    K_zt, K_lt, K_ras, K_rad = pv[K_ZT], pv[K_LT], pv[K_RAS], pv[K_RAD]
    D_f, E_f, D_r, E_r = pv[D_F], pv[E_F], pv[D_R], pv[E_R]
    T_sb, T_se = pv[T_SB], pv[T_SE]
    for i in range(29):
        out[i] = math.nan
    omega = np.empty(4)  # wheel speeds [rad/s], clamped at 0
    for i in range(4):
        omega[i] = 0.0 if x[23 + i] < 0.0 else x[23 + i]

    # inputs within the steering and acceleration limits
    u0 = _steering_rate(x[2], steer_rate, pv)
    u1 = _acceleration(x[3], accel, pv)

    kinematic = abs(x[3]) < KINEMATIC_BELOW_MPS
    cos_d, sin_d = math.cos(x[2]), math.sin(x[2])
    cos_roll = math.cos(x[6])
    sin_roll = math.sin(x[6])

    # vertical tire forces [N] (wheels: left front, right front, left rear, right rear)
    fz = np.empty(4)
    fz[0] = (x[16] + R_w * (math.cos(x[13]) - 1) - 0.5 * T_f * math.sin(x[13])) * K_zt
    fz[1] = (x[16] + R_w * (math.cos(x[13]) - 1) + 0.5 * T_f * math.sin(x[13])) * K_zt
    fz[2] = (x[21] + R_w * (math.cos(x[18]) - 1) - 0.5 * T_r * math.sin(x[18])) * K_zt
    fz[3] = (x[21] + R_w * (math.cos(x[18]) - 1) + 0.5 * T_r * math.sin(x[18])) * K_zt

    # longitudinal slips and slip angles (0 in the kinematic regime)
    slip = np.zeros(4)
    alpha = np.zeros(4)
    if not kinematic:
        # each wheel's ground speed along its heading [m/s]; the package sets a negative one
        # to 0 and then divides by it
        u_w_lf, u_w_rf, u_w_lr, u_w_rr = wheel_ground_speeds(x, a, T_f, T_r)
        if u_w_lf <= 0.0 or u_w_rf <= 0.0 or u_w_lr <= 0.0 or u_w_rr <= 0.0:
            return WHEEL_AT_REST_OVER_GROUND
        slip[0] = 1 - R_w * omega[0] / u_w_lf
        slip[1] = 1 - R_w * omega[1] / u_w_rf
        slip[2] = 1 - R_w * omega[2] / u_w_lr
        slip[3] = 1 - R_w * omega[3] / u_w_rr
        den_lf = x[3] + 0.5 * T_f * x[5]
        den_rf = x[3] - 0.5 * T_f * x[5]
        den_lr = x[3] + 0.5 * T_r * x[5]
        den_rr = x[3] - 0.5 * T_r * x[5]
        if den_lf == 0.0 or den_rf == 0.0 or den_lr == 0.0 or den_rr == 0.0:
            return SLIP_ANGLE_DIVISION
        lat_f = x[10] + a * x[5] - x[14] * (R_w - x[16])
        lat_r = x[10] - b * x[5] - x[19] * (R_w - x[21])
        alpha[0] = math.atan(lat_f / den_lf) - x[2]
        alpha[1] = math.atan(lat_f / den_rf) - x[2]
        alpha[2] = math.atan(lat_r / den_lr)
        alpha[3] = math.atan(lat_r / den_rr)

    # suspension travel [m] and its rate [m/s] at each corner
    z_SLF = (
        (h_s - R_w + x[16] - x[11]) / cos_roll - h_s + R_w + a * x[8] + 0.5 * (x[6] - x[13]) * T_f
    )
    z_SRF = (
        (h_s - R_w + x[16] - x[11]) / cos_roll - h_s + R_w + a * x[8] - 0.5 * (x[6] - x[13]) * T_f
    )
    z_SLR = (
        (h_s - R_w + x[21] - x[11]) / cos_roll - h_s + R_w - b * x[8] + 0.5 * (x[6] - x[18]) * T_r
    )
    z_SRR = (
        (h_s - R_w + x[21] - x[11]) / cos_roll - h_s + R_w - b * x[8] - 0.5 * (x[6] - x[18]) * T_r
    )
    dz_SLF = x[17] - x[12] + a * x[9] + 0.5 * (x[7] - x[14]) * T_f
    dz_SRF = x[17] - x[12] + a * x[9] - 0.5 * (x[7] - x[14]) * T_f
    dz_SLR = x[22] - x[12] - b * x[9] + 0.5 * (x[7] - x[19]) * T_r
    dz_SRR = x[22] - x[12] - b * x[9] - 0.5 * (x[7] - x[19]) * T_r

    # camber angles [rad]
    gamma = np.empty(4)
    gamma[0] = x[6] + D_f * z_SLF + E_f * _libm_pow(z_SLF, 2.0)
    gamma[1] = x[6] - D_f * z_SRF - E_f * _libm_pow(z_SRF, 2.0)
    gamma[2] = x[6] + D_r * z_SLR + E_r * _libm_pow(z_SLR, 2.0)
    gamma[3] = x[6] - D_r * z_SRR - E_r * _libm_pow(z_SRR, 2.0)

    # tire forces [N]; a zero load makes the package divide by zero in the stiffness factor
    fx = np.empty(4)
    fy = np.empty(4)
    zero_load = False
    for i in range(4):  # one call site per tire function: each is inlined once
        f0_x, den_x = _pure_longitudinal(slip[i], gamma[i], fz[i], pv)
        f0_y, mu_y, den_y = _pure_lateral(alpha[i], gamma[i], fz[i], pv)
        zero_load = zero_load or den_x == 0.0 or den_y == 0.0
        fx[i] = _combined_longitudinal(slip[i], alpha[i], f0_x, pv)
        fy[i] = _combined_lateral(slip[i], alpha[i], gamma[i], mu_y, fz[i], f0_y, pv)
    if zero_load:
        return ZERO_TIRE_LOAD
    F_x_LF, F_x_RF, F_x_LR, F_x_RR = fx[0], fx[1], fx[2], fx[3]
    F_y_LF, F_y_RF, F_y_LR, F_y_RR = fy[0], fy[1], fy[2], fy[3]
    F_z_LF, F_z_RF, F_z_LR, F_z_RR = fz[0], fz[1], fz[2], fz[3]

    # compliant joints between the sprung and unsprung masses
    delta_z_f = h_s - R_w + x[16] - x[11]
    delta_z_r = h_s - R_w + x[21] - x[11]
    delta_phi_f = x[6] - x[13]
    delta_phi_r = x[6] - x[18]
    dot_delta_phi_f = x[7] - x[14]
    dot_delta_phi_r = x[7] - x[19]
    dot_delta_z_f = x[17] - x[12]
    dot_delta_z_r = x[22] - x[12]
    dot_delta_y_f = x[10] + a * x[5] - x[15]
    dot_delta_y_r = x[10] - b * x[5] - x[20]
    delta_f = delta_z_f * sin_roll - x[27] * cos_roll - (h_raf - R_w) * math.sin(delta_phi_f)
    delta_r = delta_z_r * sin_roll - x[28] * cos_roll - (h_rar - R_w) * math.sin(delta_phi_r)
    dot_delta_f = (
        (delta_z_f * cos_roll + x[27] * sin_roll) * x[7]
        + dot_delta_z_f * sin_roll
        - dot_delta_y_f * cos_roll
        - (h_raf - R_w) * math.cos(delta_phi_f) * dot_delta_phi_f
    )
    dot_delta_r = (
        (delta_z_r * cos_roll + x[28] * sin_roll) * x[7]
        + dot_delta_z_r * sin_roll
        - dot_delta_y_r * cos_roll
        - (h_rar - R_w) * math.cos(delta_phi_r) * dot_delta_phi_r
    )
    F_RAF = delta_f * K_ras + dot_delta_f * K_rad
    F_RAR = delta_r * K_ras + dot_delta_r * K_rad

    # suspension forces [N] (bump stops and squat/lift forces neglected, as in the package)
    # (a + (-t) is a - t exactly in IEEE arithmetic: the helper keeps the package's numbers)
    roll_f = (x[6] - x[13]) * pv[K_TSF] / T_f
    roll_r = (x[6] - x[18]) * pv[K_TSR] / T_r
    F_SLF = _suspension(m_s * g * b / (2 * (a + b)), z_SLF, dz_SLF, pv[K_SF], pv[K_SDF], roll_f)
    F_SRF = _suspension(m_s * g * b / (2 * (a + b)), z_SRF, dz_SRF, pv[K_SF], pv[K_SDF], -roll_f)
    F_SLR = _suspension(m_s * g * a / (2 * (a + b)), z_SLR, dz_SLR, pv[K_SR], pv[K_SDR], roll_r)
    F_SRR = _suspension(m_s * g * a / (2 * (a + b)), z_SRR, dz_SRR, pv[K_SR], pv[K_SDR], -roll_r)

    # sums of forces [N] and moments [N m] on the sprung mass
    sumX = F_x_LR + F_x_RR + (F_x_LF + F_x_RF) * cos_d - (F_y_LF + F_y_RF) * sin_d
    sumN = (
        (F_y_LF + F_y_RF) * a * cos_d
        + (F_x_LF + F_x_RF) * a * sin_d
        + (F_y_RF - F_y_LF) * 0.5 * T_f * sin_d
        + (F_x_LF - F_x_RF) * 0.5 * T_f * cos_d
        + (F_x_LR - F_x_RR) * 0.5 * T_r
        - (F_y_LR + F_y_RR) * b
    )
    sumY_s = (F_RAF + F_RAR) * cos_roll + (F_SLF + F_SLR + F_SRF + F_SRR) * sin_roll
    sumL = (
        0.5 * F_SLF * T_f
        + 0.5 * F_SLR * T_r
        - 0.5 * F_SRF * T_f
        - 0.5 * F_SRR * T_r
        - F_RAF / cos_roll * (h_s - x[11] - R_w + x[16] - (h_raf - R_w) * math.cos(x[13]))
        - F_RAR / cos_roll * (h_s - x[11] - R_w + x[21] - (h_rar - R_w) * math.cos(x[18]))
    )
    sumZ_s = (F_SLF + F_SLR + F_SRF + F_SRR) * cos_roll - (F_RAF + F_RAR) * sin_roll
    sumM_s = (
        a * (F_SLF + F_SRF)
        - b * (F_SLR + F_SRR)
        + ((F_x_LF + F_x_RF) * cos_d - (F_y_LF + F_y_RF) * sin_d + F_x_LR + F_x_RR) * (h_s - x[11])
    )

    # sums on the unsprung masses
    front_lateral = (F_y_LF + F_y_RF) * cos_d + (F_x_LF + F_x_RF) * sin_d
    sumL_uf = _unsprung_roll_moment(
        F_SLF, F_SRF, T_f, F_RAF, h_raf, R_w, F_z_LF, F_z_RF, F_y_LF, F_y_RF, K_lt, x[13]
    ) - front_lateral * (R_w - x[16])
    sumL_ur = _unsprung_roll_moment(
        F_SLR, F_SRR, T_r, F_RAR, h_rar, R_w, F_z_LR, F_z_RR, F_y_LR, F_y_RR, K_lt, x[18]
    ) - (F_y_LR + F_y_RR) * (R_w - x[21])
    sumZ_uf = F_z_LF + F_z_RF + F_RAF * sin_roll - (F_SLF + F_SRF) * cos_roll
    sumZ_ur = F_z_LR + F_z_RR + F_RAR * sin_roll - (F_SLR + F_SRR) * cos_roll
    sumY_uf = (
        (F_y_LF + F_y_RF) * cos_d
        + (F_x_LF + F_x_RF) * sin_d
        - F_RAF * cos_roll
        - (F_SLF + F_SRF) * sin_roll
    )
    sumY_ur = (F_y_LR + F_y_RR) - F_RAR * cos_roll - (F_SLR + F_SRR) * sin_roll

    # planar motion: the kinematic single-track model at the CG below 0.1 m/s, else the forces
    if kinematic:
        lwb = a + b
        # the package's vehicle_dynamics_ks_cog applies the input constraints once more
        u0_ks = _steering_rate(x[2], u0, pv)
        u1_ks = _acceleration(x[3], u1, pv)
        beta_ks = math.atan(math.tan(x[2]) * b / lwb)
        out[0] = x[3] * math.cos(beta_ks + x[4])
        out[1] = x[3] * math.sin(beta_ks + x[4])
        out[2] = u0_ks
        out[3] = u1_ks
        out[4] = x[3] * math.cos(beta_ks) * math.tan(x[2]) / lwb
        d_beta = (b * u0) / (
            lwb
            * _libm_pow(math.cos(x[2]), 2.0)
            * (1 + _libm_pow(_libm_pow(math.tan(x[2]), 2.0) * b / lwb, 2.0))
        )
        out[5] = (
            1
            / lwb
            * (
                u1 * math.cos(x[6]) * math.tan(x[2])
                - x[3] * math.sin(x[6]) * d_beta * math.tan(x[2])
                + x[3] * math.cos(x[6]) * u0 / _libm_pow(math.cos(x[2]), 2.0)
            )
        )
    else:
        beta = math.atan(x[10] / x[3])
        vel = math.sqrt(_libm_pow(x[3], 2.0) + _libm_pow(x[10], 2.0))
        out[0] = math.cos(beta + x[4]) * vel
        out[1] = math.sin(beta + x[4]) * vel
        out[2] = u0
        out[3] = 1 / m * sumX + x[5] * x[10]
        out[4] = x[5]
        out[5] = 1 / (I_z - _libm_pow(I_xz_s, 2.0) / I_Phi_s) * (sumN + I_xz_s / I_Phi_s * sumL)

    # sprung mass: roll, pitch, lateral and vertical motion
    out[6] = x[7]
    out[7] = 1 / (I_Phi_s - _libm_pow(I_xz_s, 2.0) / I_z) * (I_xz_s / I_z * sumN + sumL)
    out[8] = x[9]
    out[9] = 1 / I_y_s * sumM_s
    out[10] = 1 / m_s * sumY_s - x[5] * x[3]
    out[11] = x[12]
    out[12] = g - 1 / m_s * sumZ_s
    # unsprung masses, front then rear: roll, lateral and vertical motion
    out[13] = x[14]
    out[14] = 1 / I_uf * sumL_uf
    out[15] = 1 / m_uf * sumY_uf - x[5] * x[3]
    out[16] = x[17]
    out[17] = g - 1 / m_uf * sumZ_uf
    out[18] = x[19]
    out[19] = 1 / I_ur * sumL_ur
    out[20] = 1 / m_ur * sumY_ur - x[5] * x[3]
    out[21] = x[22]
    out[22] = g - 1 / m_ur * sumZ_ur

    # wheel spin: the acceleration input as brake or engine torque [N m], split by T_sb, T_se
    if u1 > 0:
        T_B = 0.0
        T_E = m * R_w * u1
    else:
        T_B = m * R_w * u1
        T_E = 0.0
    out[23] = 1 / I_y_w * (-R_w * F_x_LF + 0.5 * T_sb * T_B + 0.5 * T_se * T_E)
    out[24] = 1 / I_y_w * (-R_w * F_x_RF + 0.5 * T_sb * T_B + 0.5 * T_se * T_E)
    out[25] = 1 / I_y_w * (-R_w * F_x_LR + 0.5 * (1 - T_sb) * T_B + 0.5 * (1 - T_se) * T_E)
    out[26] = 1 / I_y_w * (-R_w * F_x_RR + 0.5 * (1 - T_sb) * T_B + 0.5 * (1 - T_se) * T_E)

    # compliant joints' lateral deflections
    out[27] = dot_delta_y_f
    out[28] = dot_delta_y_r
    return REGULAR


STEP_TOO_SMALL = 4
""":func:`mb_advance`'s code where its error control asked for a step below ``h_min_s`` (not
a division by zero: a motion too fast to follow, e.g. a diverging one)."""

# Bogacki-Shampine 3(2): the third-order solution's weights and the error weights (third
# order minus the embedded second order), stages at 0, 1/2, 3/4, 1 (the last is FSAL: the
# derivative at the accepted state starts the next step).
_BS_B1, _BS_B2, _BS_B3 = 2.0 / 9.0, 1.0 / 3.0, 4.0 / 9.0
_BS_E1, _BS_E2, _BS_E3, _BS_E4 = -5.0 / 72.0, 1.0 / 12.0, 1.0 / 9.0, -1.0 / 8.0


_SINGULAR_STEP_S = 1e-6
"""A stage that divides by zero with a step this short [s] or shorter ends the integration."""


@jit
def _stage(y, h, k, c, out):
    for i in range(y.shape[0]):
        out[i] = y[i] + c * h * k[i]


@jit
def mb_advance(x, steer_rate, accel, pv, duration_s, h_s, rtol, atol, h_min_s, out):
    """Advance the multi-body state ``x`` (29,) by ``duration_s`` [s] with the input
    ``[steer_rate rad/s, accel m/s^2]`` and parameters ``pv`` held, into ``out`` (29,).

    Error-controlled Bogacki-Shampine 3(2) steps (three new derivatives per step): a step is
    accepted where every component's local error is at most ``atol + rtol * |x_i|`` (the larger
    of its start and end); the next step is scaled by ``0.9 * (1 / error)^(1/3)`` within
    [0.2, 5]. ``h_s`` is the first step tried [s] (the previous call's answer: the wheel-spin
    modes' stiffness sets it, and it changes slowly); a step cut short by the interval's end
    does not shrink it. Wheel speeds are kept >= 0 after each step, as in the package.

    Returns ``(code, next step [s], derivative evaluations)``: :data:`REGULAR` with the state
    at ``duration_s`` in ``out``; a code of :data:`SINGULAR` where the state divides by zero,
    or a stage does with a step of 1 us or less (``out`` holds that stage's state, as
    ``MbTruth.rhs`` reports it; a longer step that leaves the model is tried shorter); or
    :data:`STEP_TOO_SMALL` (``out`` holds the last accepted state).
    """
    n = x.shape[0]
    y = x.copy()
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    stage = np.empty(n)
    y_new = np.empty(n)
    for i in range(n):
        out[i] = y[i]
    code = mb_derivative(y, steer_rate, accel, pv, k1)
    evals = 1
    if code != REGULAR:
        return code, h_s, evals
    t = 0.0
    h_next = h_s
    while t < duration_s * (1.0 - 1e-12):
        last = t + h_next >= duration_s * (1.0 - 1e-12)
        h = duration_s - t if last else h_next
        evaluated = stage  # the state of the last derivative evaluated (reported on a code)
        _stage(y, h, k1, 0.5, stage)
        code = mb_derivative(stage, steer_rate, accel, pv, k2)
        if code == REGULAR:
            _stage(y, h, k2, 0.75, stage)
            code = mb_derivative(stage, steer_rate, accel, pv, k3)
        if code == REGULAR:
            for i in range(n):
                y_new[i] = y[i] + h * (_BS_B1 * k1[i] + _BS_B2 * k2[i] + _BS_B3 * k3[i])
            for i in range(23, 27):
                if y_new[i] < 0.0:
                    y_new[i] = 0.0
            evaluated = y_new
            code = mb_derivative(y_new, steer_rate, accel, pv, k4)
        evals += 3
        if code != REGULAR:
            # A stage left the model. A trial step too long for the motion can do that where
            # shorter steps would not: shorter steps first, the code once they are short.
            if h <= _SINGULAR_STEP_S:
                for i in range(n):
                    out[i] = evaluated[i]
                return code, h, evals
            h_next = h * 0.2
            continue
        error = 0.0
        for i in range(n):
            e = h * (_BS_E1 * k1[i] + _BS_E2 * k2[i] + _BS_E3 * k3[i] + _BS_E4 * k4[i])
            r = abs(e) / (atol + rtol * max(abs(y[i]), abs(y_new[i])))
            if not r <= error:  # a NaN counts as too large
                error = r
        scale = 5.0 if error == 0.0 else 0.9 * error ** (-1.0 / 3.0)
        scale = min(5.0, max(0.2, scale)) if scale == scale else 0.2
        if error <= 1.0:
            t = duration_s if last else t + h
            for i in range(n):
                y[i] = y_new[i]
                k1[i] = k4[i]
                out[i] = y[i]
            h_next = max(h_next, h * scale) if last else h * scale
        else:
            h_next = h * scale
            if h_next < h_min_s:
                return STEP_TOO_SMALL, h_next, evals
    return REGULAR, h_next, evals
