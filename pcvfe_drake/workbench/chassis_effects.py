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
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.workbench.effects import Effect, EffectParam, register_effect


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


for _cls in (AxleStiffness, RotatingInertia, WheelForceSteer):
    register_effect(_cls)
