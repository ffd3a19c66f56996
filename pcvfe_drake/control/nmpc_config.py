"""Settings of the tracking NMPC (:class:`NmpcConfig`) and its prediction models."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from pcvfe_drake.vehicle.params import VehicleParams

MODELS = ("st", "ks")
"""Prediction models: ``"st"`` single track with theta_hat, ``"ks"`` kinematic (KMPC)."""


FRICTION_CLIPS = ("", "drive", "both")
"""What of the applied acceleration :attr:`NmpcConfig.friction_clip` keeps within the friction
circle: nothing, a positive (drive) acceleration, or both signs."""


MAX_HORIZON = 400
"""Most prediction steps: 400 steps of 50 ms look 20 s ahead, farther than any braking the
course needs, while the QP's size and solve time grow with every step."""


@dataclass
class NmpcConfig:
    """Settings of the tracking NMPC (SI units; scales are Bryson-rule tolerances: the weight of
    a term is 1 / scale^2; ``None`` derives a scale from the vehicle, see :meth:`resolved`).

    Attributes:
        horizon: prediction steps N.
        dt_s: step and controller period [s].
        model: prediction model, ``"st"`` (single track with theta_hat) or ``"ks"`` (kinematic,
            the KMPC baseline).
        lateral_scale_m: lateral error tolerance [m] (None: 0.08 * wheelbase).
        course_angle_scale_rad: course-angle error tolerance [rad].
        speed_scale_mps: speed error tolerance [m/s] (None: 0.35 * sqrt(wheelbase)).
        yaw_rate_scale_radps: yaw-rate error tolerance [rad/s] vs v_ref * kappa (None: off).
        steer_rate_scale_radps: steering-rate tolerance [rad/s] (None: the vehicle's limit).
        accel_scale_mps2: acceleration tolerance [m/s^2].
        steer_rate_change_scale_radps: change of steering rate per step [rad/s] (None: 0.25 *
            the vehicle's steering-rate limit).
        accel_change_scale_mps2: change of acceleration per step [m/s^2].
        terminal_factor: weight multiplier of the last stage's state terms.
        speed_margin: reference speed <= speed_margin * sqrt(mu_hat g / |kappa|).
        long_fraction: acceleration/braking limit of the speed profile, fraction of mu_hat g.
        ref_rise_limit: below the profile, the reference speed rises from the measured speed at
            most at the profile's acceleration (``long_fraction * mu_hat g``, at most the
            vehicle's ``a_max``) over the horizon; False: the profile alone (the car then
            catches up at the friction polygon's limit and can overshoot the profile before a
            bend).
        max_speed_mps: cap on the reference speed (None or 0: the course's planned speed).
        steer_rate_fraction: share of the vehicle's steering-rate limit the reference speed
            may demand: v_ref <= steer_rate_fraction * delta_dot_max / |d delta / ds| with delta
            the kinematic steering of the course's curvature, so every drivable course is
            driven where its bends change faster than the steering can follow (the rest of
            the limit is left for correcting tracking errors). 0: no such limit (the speed
            profile then depends on friction alone).
        friction_margin: radius of the QP's friction polygon, fraction of mu_hat g.
        friction_clip: what of the applied acceleration is kept within the friction circle the
            measured lateral acceleration ``v psi_dot`` leaves of ``friction_margin * mu_hat
            g``: ``""`` nothing (the polygon alone, soft), ``"drive"`` a positive acceleration,
            ``"both"`` also braking. The prediction model has no combined slip, so a plan may
            ask for a longitudinal force the tyres cannot give while they turn at the limit.
        corridor_fraction: soft corridor half-width, fraction of the course half-width.
        slack_linear, slack_quadratic: penalties on the slacks (per unit, per unit^2).
        v_lin_min_mps: the linearisation speed is clamped to at least this [m/s].
        ks_relax_s: relaxation time of psi_dot and beta to their kinematic values (KMPC) [s].
        max_iter, eps_abs, eps_rel: OSQP settings; ``max_iter`` is the deterministic budget of
            one update (an unsolved QP after it triggers the fallback).
        time_limit_s: optional wall-clock limit of one OSQP solve [s] (e.g. 0.04 on hardware at
            20 Hz). None (default) keeps simulations deterministic: a wall-clock limit makes
            the result depend on the machine's load.
        fallback_shift_steps: how many steps of a stale plan the fallback may use.
        brake_fraction: braking deceleration of the fallback, fraction of mu_hat g.
        cold_start_distance_m: a plan whose first state is farther than this from the measured
            position is discarded (cold start).
    """

    horizon: int = 40
    dt_s: float = 0.05
    model: str = "st"
    lateral_scale_m: float | None = None
    course_angle_scale_rad: float = 0.06
    speed_scale_mps: float | None = None
    yaw_rate_scale_radps: float | None = None
    steer_rate_scale_radps: float | None = None
    accel_scale_mps2: float = 3.0
    steer_rate_change_scale_radps: float | None = None
    accel_change_scale_mps2: float = 0.5
    terminal_factor: float = 5.0
    speed_margin: float = 0.8
    long_fraction: float = 0.5
    ref_rise_limit: bool = True
    max_speed_mps: float | None = None
    steer_rate_fraction: float = 0.8
    friction_margin: float = 0.9
    friction_clip: str = ""
    corridor_fraction: float = 0.5
    slack_linear: float = 100.0
    slack_quadratic: float = 1000.0
    v_lin_min_mps: float = 1.0
    ks_relax_s: float = 0.1
    max_iter: int = 1000
    eps_abs: float = 1e-3
    eps_rel: float = 1e-3
    time_limit_s: float | None = None
    fallback_shift_steps: int = 20
    brake_fraction: float = 0.5
    cold_start_distance_m: float = 2.0

    def resolved(self, params: VehicleParams) -> NmpcConfig:
        """A copy with every ``None`` scale derived from the vehicle (validated)."""
        wb = params.L
        rate = max(abs(params.delta_dot_min), abs(params.delta_dot_max))
        cfg = dataclasses.replace(
            self,
            lateral_scale_m=self.lateral_scale_m or 0.08 * wb,
            speed_scale_mps=self.speed_scale_mps or 0.35 * math.sqrt(wb),
            steer_rate_scale_radps=self.steer_rate_scale_radps or rate,
            steer_rate_change_scale_radps=self.steer_rate_change_scale_radps or 0.25 * rate,
        )
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def need(ok, name, rule):
            if not ok:
                raise ValueError(f"NmpcConfig.{name}={getattr(self, name)!r} must be {rule}")

        need(int(self.horizon) >= 2, "horizon", ">= 2")
        need(
            int(self.horizon) <= MAX_HORIZON,
            "horizon",
            f"<= {MAX_HORIZON} steps (its QP would have {int(self.horizon) * 9} variables, and "
            "its time and memory grow with each step)",
        )
        need(
            self.max_speed_mps is None
            or (math.isfinite(self.max_speed_mps) and self.max_speed_mps >= 0),
            "max_speed_mps",
            ">= 0 m/s (0 or None: the course's planned speed)",
        )
        need(self.dt_s > 0, "dt_s", "> 0")
        need(self.model in MODELS, "model", f"one of {MODELS}")
        need(self.friction_clip in FRICTION_CLIPS, "friction_clip", f"one of {FRICTION_CLIPS}")
        for name in (
            "course_angle_scale_rad",
            "accel_scale_mps2",
            "accel_change_scale_mps2",
            "terminal_factor",
            "friction_margin",
            "corridor_fraction",
            "v_lin_min_mps",
            "ks_relax_s",
            "brake_fraction",
            "cold_start_distance_m",
        ):
            need(getattr(self, name) > 0, name, "> 0")
        for name in (
            "lateral_scale_m",
            "speed_scale_mps",
            "steer_rate_scale_radps",
            "steer_rate_change_scale_radps",
            "yaw_rate_scale_radps",
            "time_limit_s",
        ):
            value = getattr(self, name)
            need(value is None or value > 0, name, "> 0 or None")
        need(0 < self.speed_margin <= 1, "speed_margin", "in (0, 1]")
        need(0 < self.long_fraction <= 1, "long_fraction", "in (0, 1]")
        need(0 <= self.steer_rate_fraction <= 1, "steer_rate_fraction", "in [0, 1] (0: off)")
        need(self.slack_linear >= 0 and self.slack_quadratic > 0, "slack_quadratic", "> 0")
        need(int(self.max_iter) >= 1, "max_iter", ">= 1")
        for name in ("eps_abs", "eps_rel"):  # OSQP's tolerances: it refuses a negative one
            value = getattr(self, name)
            need(math.isfinite(value) and value >= 0, name, ">= 0 (an OSQP tolerance)")
        need(self.eps_abs > 0 or self.eps_rel > 0, "eps_abs", "> 0 where eps_rel is 0")
        need(int(self.fallback_shift_steps) >= 0, "fallback_shift_steps", ">= 0")
