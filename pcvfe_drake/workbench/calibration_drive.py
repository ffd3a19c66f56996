"""A standard calibration drive on one known surface, driven on the multi-body truth.

What a test driver does to learn a car's handling on a proving ground, in four parts, each a
closed-loop driver on the car's state (as a driver sees it) with a proportional steering-angle
loop and a proportional speed loop. Between the manoeuvres the driver holds the heading (the
circles' yaw-rate loop at zero curvature: on a low-grip surface the car's yaw mode can be
unstable at speed, and a driver who only catches a side slip lets it diverge) and changes
speed within a share of the surface's grip (:data:`SPEED_BRAKE_G`, :data:`SPEED_DRIVE_G`):

* **steady-state circles** at rising speed: a circle of :data:`CIRCLE_RADIUS_M` driven at
  lateral accelerations of :data:`CIRCLE_LEVELS` times ``mu g``, left then right (the
  understeer gradient, the axles' stiffness and, near the limit, the tyre's peak; both
  directions so that effects which switch with the cornering direction show as such). The
  driver holds the circle's yaw rate ``v / R`` with a PI loop on the steering angle;
* **steering steps** at :data:`STEP_SPEED_MPS`: steps of the wheel angle that aim at
  :data:`STEP_LEVELS` times ``mu g``, both signs, held 2 s (the transient: yaw inertia, lags);
* **a sine sweep** at the same speed, from 0.2 to 1.5 Hz at half the friction limit (the
  amplitude falls where the steering rate limit needs it; the frequency response);
* **braking**: straight stops at :data:`BRAKE_LEVELS` times ``g`` (capped below the surface's
  grip), and a stop in a bend (the loads' transfer and combined slip).

The slalom of the paper's evaluation drives its bends at 4-12 m/s with radii of about 10-20 m;
the circles (15 m) and the steps (10 m/s) cover that range, on one surface whose friction is
known (``mu``; default the tyre's nominal peak: dry asphalt). Everything logged is what a car
measures: the measured single-track state and the commanded inputs
(``pcvfe_drake.runs.drivelog.REQUIRED_COLUMNS``), with survey-grade INS noise by default.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pcvfe_drake.vehicle.measurement_noise import SURVEY_INS_NOISE, MeasurementNoise
from pcvfe_drake.vehicle.params import load_vehicle

CIRCLE_RADIUS_M = 15.0
"""Radius of the steady-state circles [m] (the slalom's bends are 10-20 m)."""
CIRCLE_LEVELS = (0.2, 0.4, 0.55, 0.7, 0.8, 0.88)
"""Lateral accelerations of the circles, as fractions of ``mu g``."""
CIRCLE_HOLD_S = 6.0
"""Time at each circle speed [s] (the first ~2 s settle the speed)."""
STEP_SPEED_MPS = 10.0
"""Speed of the steering steps and the sine sweep [m/s]."""
STEP_LEVELS = (0.3, 0.6)
"""Steering steps aimed at these fractions of ``mu g`` (kinematic steering angle)."""
STEP_HOLD_S = 2.0
STEP_GAP_S = 1.5
SWEEP_S = 20.0
"""Duration of the sine sweep [s] (0.2 to 1.5 Hz, linear in frequency)."""
SWEEP_LEVEL = 0.5
BRAKE_LEVELS = (0.3, 0.6)
"""Deceleration of the straight stops, in g (each at most 0.8 of the surface's mu)."""
BRAKE_FROM_MPS = 14.0
SPEED_BRAKE_MPS2, SPEED_DRIVE_MPS2 = 3.0, 2.0
"""The speed loop's deceleration and acceleration limits [m/s^2] (outside the braking tests)."""
SPEED_BRAKE_G, SPEED_DRIVE_G = 0.3, 0.2
"""The same limits as shares of the surface's grip ``mu g``: about what 3 and 2 m/s^2 ask of dry
asphalt. On a low-grip surface a driver changes speed as gently; at full 3 and 2 m/s^2 a
rear-driven car at 0.3 spins leaving a circle near its limit."""
BRAKE_TO_MPS = 5.0


@dataclass(frozen=True)
class Segment:
    """One part of the programme: ``kind`` circle | step | sweep | brake | cruise."""

    kind: str
    duration_s: float
    v_mps: float
    value: float = 0.0
    """circle: signed curvature [1/m]; step: signed wheel angle [rad]; sweep: amplitude
    [rad]; brake: deceleration [m/s^2] (a circle's curvature in ``curvature``)."""
    curvature: float = 0.0


def programme(vehicle: str, mu: float) -> list[Segment]:
    """The calibration programme's segments (module docstring) for a surface of friction
    ``mu``."""
    vp = load_vehicle(vehicle)
    g, wheelbase = vp.g, vp.lf + vp.lr
    out = [Segment("cruise", 4.0, 8.0)]
    for sign in (1.0, -1.0):
        for level in CIRCLE_LEVELS:
            v = math.sqrt(level * mu * g * CIRCLE_RADIUS_M)
            out.append(Segment("circle", CIRCLE_HOLD_S, v, sign / CIRCLE_RADIUS_M))
        out.append(Segment("cruise", 3.0, STEP_SPEED_MPS))
    v = STEP_SPEED_MPS
    for level in STEP_LEVELS:
        for sign in (1.0, -1.0):
            delta = sign * wheelbase * level * mu * g / v**2
            out.append(Segment("step", STEP_HOLD_S, v, delta))
            out.append(Segment("cruise", STEP_GAP_S, v))
    out.append(Segment("sweep", SWEEP_S, v, wheelbase * SWEEP_LEVEL * mu * g / v**2))
    for level in BRAKE_LEVELS:
        decel = min(level * g, 0.8 * mu * g)
        out.append(Segment("cruise", 5.0, BRAKE_FROM_MPS))
        out.append(Segment("brake", 6.0, BRAKE_TO_MPS, decel))
    radius = 2.0 * CIRCLE_RADIUS_M
    v_bend = math.sqrt(0.4 * mu * g * radius)
    out.append(Segment("circle", 5.0, v_bend, 1.0 / radius))
    out.append(Segment("brake", 5.0, BRAKE_TO_MPS, 0.25 * mu * g, curvature=1.0 / radius))
    out.append(Segment("cruise", 3.0, BRAKE_TO_MPS))
    return out


def programme_duration_s(segments: list[Segment]) -> float:
    return float(sum(s.duration_s for s in segments))


def calibration_drive(
    vehicle: str = "ford_escort",
    friction_mapping: str = "peak_and_stiffness",
    mu: float | None = None,
    rate_hz: float = 20.0,
    seed: int = 0,
    noise: MeasurementNoise | None = SURVEY_INS_NOISE,
    progress: Callable[[float], None] | None = None,
    segments: list[Segment] | None = None,
) -> pd.DataFrame:
    """A drive log of the calibration programme on CommonRoad's multi-body model
    (``pcvfe_drake.vehicle.mb_truth.MbTruth``) on one surface of friction ``mu`` (default: the
    tyre's nominal peak), measured with ``noise``; ``progress(fraction)`` is called as it
    drives; ``segments``: another programme (default :func:`programme` for ``vehicle`` and
    ``mu``)."""
    from pcvfe_drake.vehicle.mb_truth import MbTruth, st_state
    from pcvfe_drake.workbench.synth import _to_log

    vp = load_vehicle(vehicle)
    truth = MbTruth(vehicle, friction_scaling=friction_mapping)
    mu = truth.mu_nominal if mu is None else float(mu)
    if not (math.isfinite(mu) and mu > 0):
        raise ValueError(f"calibration surface mu={mu!r} must be > 0")
    segments = programme(vehicle, mu) if segments is None else list(segments)
    dt = 1.0 / rate_hz
    plan = [s for s in segments for _ in range(int(round(s.duration_s / dt)))]
    n = len(plan)
    starts = np.cumsum([0] + [int(round(s.duration_s / dt)) for s in segments])
    first = {int(k) for k in starts[:-1]}
    wheelbase = vp.lf + vp.lr
    rate_max = 0.9 * min(abs(vp.delta_dot_min), vp.delta_dot_max)
    # the speed loop's limits: a share of the surface's grip, as on dry asphalt
    brake_max = min(SPEED_BRAKE_MPS2, SPEED_BRAKE_G * mu * vp.g)
    drive_max = min(SPEED_DRIVE_MPS2, SPEED_DRIVE_G * mu * vp.g)
    x_mb = truth.initial_state(np.array([0.0, 0.0, 0.0, plan[0].v_mps, 0.0, 0.0, 0.0]))
    states = np.empty((n, 7))
    steer_log = np.empty(n)
    acc_log = np.empty(n)
    yaw_integral, t_seg = 0.0, 0.0
    for k in range(n):
        seg = plan[k]
        if k in first:
            yaw_integral, t_seg = 0.0, 0.0
        x = st_state(x_mb)
        states[k] = x
        delta, v, r = x[2], x[3], x[5]
        d_rate = 0.0
        if seg.kind in ("circle", "cruise", "brake"):
            # the path's yaw rate v kappa held by a PI loop (0 on a straight: the heading)
            kappa = seg.value if seg.kind == "circle" else seg.curvature
            error = v * kappa - r
            yaw_integral = float(np.clip(yaw_integral + 0.3 * error * dt, -0.2, 0.2))
            d_des = math.atan(wheelbase * kappa) + 0.15 * error + yaw_integral
        elif seg.kind == "step":
            d_des = seg.value
        elif seg.kind == "sweep":
            freq = 0.2 + (1.5 - 0.2) * t_seg / seg.duration_s
            amp = min(seg.value, rate_max / (2.0 * math.pi * freq))
            phase = 2.0 * math.pi * (0.2 * t_seg + 0.5 * (1.5 - 0.2) * t_seg**2 / seg.duration_s)
            d_des = amp * math.sin(phase)
            d_rate = amp * 2.0 * math.pi * freq * math.cos(phase)
        else:
            raise ValueError(f"calibration programme: unknown segment kind {seg.kind!r}")
        d_des += 0.5 * x[6] if seg.kind in ("cruise", "brake") else 0.0  # catch a slide
        gain = 8.0 if seg.kind == "step" else 3.0
        steer = float(np.clip(d_rate + gain * (d_des - delta), -rate_max, rate_max))
        if seg.kind == "brake":
            acc = -seg.value if v > seg.v_mps else float(np.clip(0.8 * (seg.v_mps - v), -1, 1))
        else:
            acc = float(np.clip(0.8 * (seg.v_mps - v), -brake_max, drive_max))
        steer_log[k], acc_log[k] = steer, acc
        if k < n - 1:
            x_mb = truth.integrate(x_mb, [steer, acc], mu, dt)
        t_seg += dt
        if progress is not None and (k % max(1, n // 50) == 0 or k == n - 1):
            progress((k + 1) / n)
    df = _to_log(states, steer_log, acc_log, dt, noise, seed + 101)
    df["segment"] = [s.kind for s in plan]
    return df
