"""Effects of the chassis that a single-track model leaves out, found on CommonRoad's
multi-body model (``pcvfe_drake.vehicle.mb_truth``) with the workbench (docs/workbench.md,
"Worked example: the multi-body truth").

* ``axle_stiffness``: the axles' effective cornering stiffnesses differ from the tyre's
  ``C_S``: body roll cambers the wheels (camber thrust, the Pacejka terms ``p_vy3``,
  ``p_hy3``), the suspension's lateral compliance and the two wheels' different slip angles
  change the force per radian of the single-track slip angle, differently front and rear.
  ``C_Sf' = k_f C_Sf``, ``C_Sr' = k_r C_Sr``; it changes the stiffness only, never the peak of
  a ``friction_is_peak`` tyre.
* ``wheel_force_steer``: the front wheels' drive/brake force turns with the steering and
  the front lateral force brakes the car (cornering drag).
* ``rotating_inertia``: the command is a wheel torque ``m R_w a`` (CommonRoad's multi-body
  model: engine torque ``T_E = m R_w a`` when driving, brake torque ``T_B = m R_w a`` when
  braking), part of which spins the wheels up: the car accelerates by
  ``a m / (m + m_rot)`` with the rotating mass equivalent ``m_rot = sum I_w / R_w^2`` (four
  wheels of 1.7 kg m^2 on 0.344 m: 57 kg, 4.7 % of the Ford Escort's mass).
* ``track_slip``: an axle's two wheels run at different slips in a bend (the track width;
  one steering angle for both front wheels): where the tyre saturates the axle makes less
  side force than the law at the single-track slip.
* ``suspension_lag``: the axle loads follow the longitudinal acceleration through the body's
  pitch mode (a damped second-order mode), not instantly: in CommonRoad's multi-body model the
  tyre loads come from the deflection of the tyres under the unsprung masses, which the
  suspension springs and dampers load as the sprung mass pitches (no anti-dive or anti-squat
  geometry: "squat/lift forces neglected"); ``studies/mb_suspension/mb_suspension.py``
  measures the mode on the Ford Escort.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter, ss2tf

from pcvfe_drake.models.effects import Effect, EffectParam, register_effect


class AxleStiffness(Effect):
    """Effective axle cornering stiffness: ``C_Sf' = k_f C_Sf``, ``C_Sr' = k_r C_Sr``.

    With the linear tyre the front force is ``mu k_f C_Sf Fz_f alpha_f`` (rear alike); with
    ``peak_tyre`` the small-slip stiffness is scaled and the peak ``mu Fz`` is not. Null:
    ``k_f = k_r = 1``. Residual signature: the yaw-rate residual follows the steering angle
    and the side slip (a stiffness error front against rear shifts the car's steady yaw
    gain and its slip).
    """

    name = "axle_stiffness"
    description = "effective axle cornering stiffness, C_Sf' = k_f C_Sf, C_Sr' = k_r C_Sr"
    params = (
        EffectParam("k_f", "-", 0.4, 2.5, 1.0, 0.05, 1.0, "front stiffness factor"),
        EffectParam("k_r", "-", 0.4, 2.5, 1.0, 0.05, 1.0, "rear stiffness factor"),
    )
    signature_state = "psi_dot"
    signature_label = "steering angle and side slip x speed"

    def cornering_stiffness(self, c_s, ctx, p):
        return c_s * (p["k_f"] if ctx.axle == "front" else p["k_r"])

    def stiffness_factor(self, p):
        return np.maximum(np.maximum(p["k_f"], p["k_r"]), 1.0)

    def signature_regressors(self, data):
        v = data.x[:, 3:4]
        return np.concatenate([data.x[:, 2:3] * v, data.x[:, 6:7] * v], axis=1)


class RotatingInertia(Effect):
    """Rotating mass: the car accelerates by ``a m / (m + m_rot)`` for a command ``a``.

    The command is a torque at the wheels (``m R_w a``); the wheels' inertia takes
    ``m_rot a_x`` of it (``m_rot = sum I_w / R_w^2``), driving and braking alike. Null:
    ``m_rot = 0``. Residual signature: the speed residual follows the acceleration command
    (as a speed-sensor scale error does; the two differ in what the sensor reports at
    constant speed).
    """

    name = "rotating_inertia"
    description = "rotating mass of the wheels, a_x = a m / (m + m_rot)"
    params = (EffectParam("m_rot", "kg", 0.0, 400.0, 50.0, 10.0, 0.0, "rotating mass equivalent"),)
    signature_state = "v"
    signature_label = "acceleration command"

    def accel(self, accel, ctx, p):
        m = ctx.vehicle.m
        return accel * m / (m + p["m_rot"])

    def signature_regressors(self, data):
        return data.u[:, 1:2]


class WheelForceSteer(Effect):
    """The front wheels' forces turn with the steering (the single-track model drops it).

    A front-wheel-driven car with front-biased brakes (CommonRoad's Ford Escort: all drive
    torque and 76 % of the brake torque on the front axle) pushes its front wheels along their
    own heading: the front longitudinal force ``F_xf = m a s`` (``s = s_drive`` for a > 0,
    ``s_brake`` below) adds ``F_xf sin(delta)`` to the front lateral force (so to the yaw
    moment and the slip), and the front lateral force takes ``k_drag F_yf sin(delta) / m`` off
    the longitudinal acceleration (cornering drag; 1 = the rotated force). Null: all three 0.
    The shares are bounded by 1.5, not 1: an *effective* share (a front-driven car's is 1,
    a bound a fit must be free to reach).
    Residual signature: the yaw-rate residual follows the acceleration command times the
    steering angle.
    """

    name = "wheel_force_steer"
    description = "front wheel forces turn with the steering: F_y,f += F_xf sin(delta)"
    params = (
        EffectParam("s_drive", "-", 0.0, 1.5, 0.5, 0.1, 0.0, "front share of drive force"),
        EffectParam("s_brake", "-", 0.0, 1.5, 0.5, 0.1, 0.0, "front share of brake force"),
        EffectParam("k_drag", "-", 0.0, 2.0, 1.0, 0.1, 0.0, "cornering drag factor"),
    )
    signature_state = "psi_dot"
    signature_label = "acceleration command x steering angle"

    def body_forces(self, fyf, fyr, ctx, p):
        share = np.where(ctx.accel > 0, p["s_drive"], p["s_brake"])
        fxf = ctx.vehicle.m * ctx.accel * share
        sin_d = np.sin(ctx.delta_wheel)
        return fxf * sin_d, 0.0, -p["k_drag"] * fyf * sin_d / ctx.vehicle.m

    def signature_regressors(self, data):
        return (data.u[:, 1] * data.x[:, 2])[:, None]


def wheel_slip_offsets(x, lever, track):
    """Slips [rad] of an axle's left and right wheels relative to the single-track slip:
    ``atan(V / U) - atan(V / (U +- track r / 2))`` with ``U = v cos(beta)`` and ``V = v
    sin(beta) + lever r`` the axle's velocities (``lever``: lf front, -lr rear) and ``r`` the
    yaw rate, for states ``x`` (N, 7) and a track width ``track`` [m] (N,)."""
    return _axle_slip_offsets(_wheel_velocities(x, track), lever)


def _wheel_velocities(x, track):
    """The parts of :func:`wheel_slip_offsets` both axles share: ``(U, v sin(beta), r, U of
    the left wheel, U of the right wheel)``."""
    v, r, beta = x[:, 3], x[:, 5], x[:, 6]
    u = np.maximum(v * np.cos(beta), 0.5)
    half = 0.5 * track * r
    floor = 0.1 * u
    return u, v * np.sin(beta), r, np.maximum(u + half, floor), np.maximum(u - half, floor)


def _axle_slip_offsets(parts, lever):
    u, side, r, u_left, u_right = parts
    w = side + lever * r
    centre = np.arctan2(w, u)
    return centre - np.arctan2(w, u_left), centre - np.arctan2(w, u_right)


MAX_LOAD_SHIFT = 0.9
"""Largest share of an axle's load ``track_slip`` moves to one wheel [-] (keeps both loaded)."""


class TrackSlip(Effect):
    """The two wheels of an axle run at different slips and loads (track width).

    A single-track model puts an axle's wheels at one point; on a car they are ``t`` apart
    and in a bend the inner wheel moves slower along the car than the outer one, at the same
    lateral velocity ``V``: the left and right wheels see the slips ``delta - atan(V / (U +-
    t r / 2))`` (``U = v cos(beta)``, ``V = v sin(beta) + lf r`` at the front, ``v sin(beta)
    - lr r`` at the rear), which differ by about ``t r V / U^2``, largest in slow tight bends
    (``V / U`` is about the steering angle at the front). With one steering angle for both
    front wheels (parallel steering, as CommonRoad's multi-body model) the inner wheel works
    at the larger slip; Ackermann geometry steers it more and takes much of the difference
    away (``t`` is then an effective track, smaller than the real one). The lateral load
    transfer weights the two: the outer wheel carries ``(1 + k_lt a / g) / 2`` of the axle's
    load, the inner one the rest (``a = v r``; on a real car ``k_lt`` is about ``2 h_roll /
    t``, positive; CommonRoad's multi-body Ford Escort loads the inner wheel, ``k_lt``
    negative, ``studies/peak_bias/front_axle_gap.py``). Where the tyre saturates, the mean of the
    concave law over the two slips is less than the law at the mean slip, so the axle makes
    less side force than the single-track model at its own slip (``wheel_slips`` hook).

    ``studies/peak_bias/front_axle_gap.py`` measures the two slips and the axle's shortfall on the
    multi-body Ford Escort.

    With a linear tyre the effect is null (the load-weighted mean of a linear law over two
    slips whose shares balance is the law at the single-track slip, up to the load term
    times the slip difference). It shows with a saturating tyre (``peak_tyre``,
    ``tire_saturation``) near the limit. Null: ``t = 0`` (``k_lt`` then does nothing). One
    width for both axles: the rear wheels' slips differ little (``V`` is small at the rear:
    in a slow steady bend ``v sin(beta)`` is near ``lr r``), so a separate rear width is not
    identifiable; the Ford Escort's tracks are 1.39 and 1.42 m.
    Residual signature: the yaw-rate residual follows ``(r V_f / U^2)^2`` signed by
    the cornering direction (the front axle's shortfall grows with the square of the slip
    difference).
    """

    name = "track_slip"
    description = (
        "track width: the wheels at slips alpha + atan(V / U) - atan(V / (U +- t r / 2)), the "
        "outer one with (1 + k_lt v r / g) / 2 of the load; the axle force the weighted mean"
    )
    params = (
        EffectParam("t", "m", 0.0, 2.5, 1.4, 0.1, 0.0, "(effective) track width, both axles"),
        EffectParam("k_lt", "-", -1.5, 1.5, 0.0, 0.1, 0.0, "outer wheel's load share per g"),
    )
    signature_state = "psi_dot"
    signature_label = "(r V_f / U^2)^2 x cornering direction"

    def wheel_slips(self, ctx, p):
        vp = ctx.vehicle
        lever = vp.lf if ctx.axle == "front" else -vp.lr
        both = ctx.cache.get(self.name)  # what the axles share, formed once (ctx.cache)
        if both is None or both[0] is not ctx.x or both[1] is not p:
            shift = p["k_lt"] * ctx.x[:, 3] * ctx.x[:, 5] / vp.g
            shift = np.minimum(np.maximum(shift, -MAX_LOAD_SHIFT), MAX_LOAD_SHIFT)
            # a left bend (a > 0): the left wheel is inner
            both = (ctx.x, p, _wheel_velocities(ctx.x, p["t"]), 0.5 * (1.0 - shift))
            ctx.cache[self.name] = both
        left, right = _axle_slip_offsets(both[2], lever)
        return left, right, both[3]

    def signature_regressors(self, data):
        x = data.x
        u = np.maximum(x[:, 3] * np.cos(x[:, 6]), 1.0)
        w = x[:, 3] * np.sin(x[:, 6]) + 1.0 * x[:, 5]
        spread = x[:, 5] * w / u**2
        return (spread**2 * np.sign(x[:, 5]))[:, None]


TAU_MIN_S = 0.04
"""``suspension_lag``'s mode runs with a time constant of at least this [s] (4 Hz); below it a
fraction ``tau / TAU_MIN_S`` of the load moves through the mode and the rest instantly, so
``tau = 0`` is exactly the baseline and the model is continuous in ``tau``."""
RK4_STABLE_HLAMBDA = 2.5
"""Largest integration step x |eigenvalue| the mode asks for (the model's RK4 rule)."""


def mode_transition(tau, zeta, t: float):
    """Transition matrix entries ``(p11, p12, p21, p22)`` (each (N,)) of the damped mode
    ``q'' = (a - q) / tau^2 - 2 zeta q' / tau`` over ``t`` seconds for the error state
    ``[q - a, q']`` with ``a`` held constant: under-, critically and over-damped alike, written
    with decaying exponentials only (no overflow for small ``tau``)."""
    tau = np.maximum(np.asarray(tau, dtype=float), 1e-4)
    zeta = np.asarray(zeta, dtype=float)
    omega = 1.0 / tau
    sigma = zeta * omega
    wd2 = omega**2 * (1.0 - zeta**2)
    root = np.sqrt(np.abs(wd2))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        decay = np.exp(-sigma * t)
        # under-damped: cos and sin / omega_d
        c_u = decay * np.cos(root * t)
        s_u = decay * np.sin(root * t) / np.where(root > 0, root, 1.0)
        # over-damped: the two real poles, the slow one as omega / (zeta + sqrt(zeta^2 - 1))
        slow = np.exp(-omega * t / (zeta + np.sqrt(np.maximum(zeta**2 - 1.0, 0.0))))
        fast = np.exp(-(sigma + root) * t)
        c_o = 0.5 * (slow + fast)
        s_o = 0.5 * (slow - fast) / np.where(root > 0, root, 1.0)
    critical = np.abs(wd2) * t * t < 1e-10
    c = np.where(critical, decay, np.where(wd2 > 0, c_u, c_o))
    s = np.where(critical, decay * t, np.where(wd2 > 0, s_u, s_o))
    return c + sigma * s, s, -(omega**2) * s, c - sigma * s


ACCEL_CORRECTION_S = 1.0
"""Length [s] of the trailing mean of (speed rate - command) in :func:`logged_acceleration`."""


def logged_acceleration(data) -> np.ndarray:
    """The car's longitudinal acceleration [m/s^2] per sample step (n,): the acceleration
    command (its steps as logged, noise-free) plus the trailing ``ACCEL_CORRECTION_S`` mean of
    the measured speed's rate minus the command (resistances, the drivetrain; slow, so the
    speed noise averages out: ~0.02 m/s^2 at 20 Hz with 0.015 m/s of speed noise)."""
    cmd = np.asarray(data.u[:, 1], dtype=float)
    if data.n < 2:
        return cmd.copy()
    slope = np.diff(data.x[:, 3]) / data.dt
    gap = np.concatenate([slope - cmd[:-1], [slope[-1] - cmd[-2]]])
    width = max(1, int(round(ACCEL_CORRECTION_S / data.dt)))
    csum = np.concatenate([[0.0], np.cumsum(gap)])
    k = np.arange(data.n)
    lo = np.maximum(k - width, 0)
    correction = (csum[k] - csum[lo]) / np.maximum(k - lo, 1)
    correction[0] = 0.0
    return cmd + correction


class SuspensionLag(Effect):
    """Longitudinal load transfer through the suspension's pitch mode (a damped second-order
    mode) instead of the single-track model's instantaneous one.

    The load-transfer acceleration ``q`` [m/s^2] follows the longitudinal acceleration
    ``a_x`` that the baseline transfers instantly (the command plus the ``longitudinal``
    resistances)::

        tau^2 q'' + 2 zeta tau q' + q = a_x,     Fz_f = m (g l_r - q h) / L,  Fz_r = ...

    natural frequency ``1 / (2 pi tau)``, damping ratio ``zeta``; in steady state ``q = a_x``
    (the rigid-body moment balance), so only the dynamics change. The states ``(q, q')`` are
    integrated with the model (RK4; the effect asks for substeps only when the mode is
    faster than the sample rate allows). Below ``TAU_MIN_S`` the mode keeps that time
    constant and only the fraction ``tau / TAU_MIN_S`` of the load moves through it:
    ``tau = 0`` is exactly the baseline. At a window start the mode is run over the log's
    acceleration (:func:`logged_acceleration`). ``studies/mb_suspension/mb_suspension.py`` measures
    the mode on CommonRoad's multi-body Ford Escort; a car body's pitch mode is under-damped, so
    ``zeta`` is bounded by 1 (an over-damped, fast mode would absorb the misfit of other
    effects).

    Null: ``tau = 0`` (``zeta`` then does nothing). Residual signature: the yaw-rate residual
    follows the change of the acceleration command times the lateral acceleration (cornering
    while the load moves).
    """

    name = "suspension_lag"
    description = (
        "axle loads follow a_x through the pitch mode: tau^2 q'' + 2 zeta tau q' + q = a_x"
    )
    params = (
        EffectParam("tau", "s", 0.0, 0.5, 0.12, 0.02, 0.0, "1 / natural angular frequency"),
        EffectParam("zeta", "-", 0.05, 1.0, 0.3, 0.05, 0.3, "damping ratio"),
    )
    state_names = ("q", "q_rate")
    signature_state = "psi_dot"
    signature_label = "change of the acceleration command x lateral acceleration"
    starts = ((0.12, 0.3), (0.06, 0.7), (0.25, 0.3))

    def load_transfer(self, a_x, ctx, p):
        w = np.clip(np.asarray(p["tau"], dtype=float) / TAU_MIN_S, 0.0, 1.0)
        return a_x + w * (ctx.states[:, 0] - a_x)

    def state_rates(self, ctx, delta_cmd, p):
        tau = np.maximum(np.asarray(p["tau"], dtype=float), TAU_MIN_S)
        q, q_rate = ctx.states[:, 0], ctx.states[:, 1]
        out = np.empty((q.size, 2))
        out[:, 0] = q_rate
        out[:, 1] = (ctx.a_long - q) / tau**2 - 2.0 * p["zeta"] * q_rate / tau
        return out

    def max_step(self, p):
        tau = np.maximum(np.asarray(p["tau"], dtype=float), TAU_MIN_S)
        zeta = np.asarray(p["zeta"], dtype=float)
        fastest = (zeta + np.sqrt(np.maximum(zeta**2 - 1.0, 0.0))) / tau
        return float(RK4_STABLE_HLAMBDA / np.max(np.maximum(fastest, 1.0 / tau)))

    def initial_states(self, data, starts, p):
        # the mode run over the log's acceleration (held over each sample step, as in the
        # rollout), from rest in its first value
        a = logged_acceleration(data)
        du = a - a[0]
        tau = np.asarray(p["tau"], dtype=float)
        zeta = np.asarray(p["zeta"], dtype=float)
        out = np.empty((len(starts), 2))
        pairs = np.stack([tau, zeta], axis=1)
        for value in np.unique(pairs, axis=0):
            rows = np.all(pairs == value, axis=1)
            tau_mode = max(value[0], TAU_MIN_S)
            p11, p12, p21, p22 = (float(v) for v in mode_transition(tau_mode, value[1], data.dt))
            phi = np.array([[p11, p12], [p21, p22]])
            gain = np.array([[1.0 - p11], [-p21]])
            num, den = ss2tf(phi, gain, np.eye(2), np.zeros((2, 1)))
            q = a[0] + lfilter(num[0], den, du)
            q_rate = lfilter(num[1], den, du)
            out[rows, 0] = q[starts[rows]]
            out[rows, 1] = q_rate[starts[rows]]
        return out

    def signature_regressors(self, data):
        jerk = np.concatenate([[0.0], np.diff(data.u[:, 1])]) / data.dt
        return (jerk * data.x[:, 3] * data.x[:, 5])[:, None]


for _cls in (AxleStiffness, RotatingInertia, WheelForceSteer, SuspensionLag, TrackSlip):
    register_effect(_cls)
