"""Friction-aware reference speed over a course (:func:`speed_profile`).

Speed profile: :func:`speed_profile` gives v_ref(s) <= ``speed_margin`` * sqrt(mu g / |kappa|),
at most the speed at which following the course's steering ``atan(L kappa)`` needs a given
steering rate, capped by a cruise speed, with forward (acceleration) and backward (braking)
passes whose limits are a fraction of mu g. The passes are closed-form cumulative minima (no
Python loop), so the profile is cheap to recompute whenever the friction estimate changes.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from pcvfe_drake.control.course import Course
from pcvfe_drake.vehicle.params import G_MPS2


@dataclass(frozen=True)
class SpeedProfile:
    """Reference speed over the course samples, with its time parametrisation.

    Attributes:
        v: reference speed at each course sample [m/s] (shape (n,)).
        t: time at which each sample is reached from s = 0 [s] (shape (n + 1,), ``t[n]`` is the
            lap time).
        mu: friction value(s) the profile was built for.
    """

    course: Course
    v: np.ndarray
    t: np.ndarray
    mu: float | np.ndarray

    @property
    def lap_time(self) -> float:
        return float(self.t[-1])

    @cached_property
    def _v_closed(self) -> np.ndarray:
        """``v`` with its first sample repeated at the end (interpolation across s = length),
        built once: the controller interpolates twice per update, and a copy of the whole
        course's speeds each time cost more than the interpolation (``v`` is never written)."""
        return np.append(self.v, self.v[0])

    def speed_at(self, s) -> np.ndarray:
        """Reference speed [m/s] at arc length(s) ``s`` (linear interpolation, wrapped)."""
        i, t = self.course.segment_at(s)
        vc = self._v_closed
        return vc[i] + t * (vc[i + 1] - vc[i])

    def advance(self, s0: float, times) -> np.ndarray:
        """Arc lengths (unwrapped, >= s0) reached after ``times`` [s] when starting at ``s0``."""
        c = self.course
        s0w = float(c.wrap_s(s0))
        t0 = float(np.interp(s0w, np.append(c.s, c.length), self.t))
        tt = t0 + np.asarray(times, dtype=float)
        laps = np.floor(tt / self.lap_time)
        s_grid = np.append(c.s, c.length)
        s = np.interp(tt - laps * self.lap_time, self.t, s_grid) + laps * c.length
        return s - c.wrap_s(s0) + s0


def speed_profile(
    course: Course,
    mu,
    *,
    v_max: float | None = None,
    speed_margin: float = 0.8,
    long_fraction: float = 0.5,
    a_drive_max: float = np.inf,
    v_min: float = 0.5,
    g: float = G_MPS2,
    steer_rate_max: float = 0.0,
    wheelbase_m: float = 0.0,
) -> SpeedProfile:
    """Friction-limited reference speed over a course.

    v(s) <= ``speed_margin`` * sqrt(mu g / |kappa(s)|), <= ``v_max`` (default: the course's
    planned speed), >= ``v_min``; then forward and backward passes with acceleration and braking
    limits ``long_fraction`` * mu g (the drive side also <= ``a_drive_max``). With the defaults the
    combined demand stays inside the friction circle: lateral (0.8^2 = 0.64) and longitudinal
    (0.5) fractions of mu g give sqrt(0.64^2 + 0.5^2) = 0.81 < 1.

    Args:
        course: the course.
        mu: friction coefficient the controller believes, a scalar or one value per course sample.
        steer_rate_max: steering rate [rad/s] the reference may demand; with ``wheelbase_m`` > 0
            the speed is at most ``steer_rate_max / |d delta / ds|`` where delta = atan(L kappa)
            is the kinematic steering along the course (0: no such limit).
    """
    mu_arr = np.broadcast_to(np.asarray(mu, dtype=float), course.s.shape)
    if not np.all(np.isfinite(mu_arr)) or np.any(mu_arr <= 0):
        raise ValueError(f"speed_profile: mu must be finite and > 0, got {mu!r}")
    for name, value in (("speed_margin", speed_margin), ("long_fraction", long_fraction)):
        if not 0 < value <= 1:
            raise ValueError(f"speed_profile: {name}={value!r} must be in (0, 1]")
    v_cap = course.speed if v_max is None or v_max <= 0 else float(v_max)
    k = np.maximum(np.abs(course.curvature), 1e-9)
    v = np.minimum(speed_margin * np.sqrt(mu_arr * g / k), v_cap)
    if steer_rate_max > 0 and wheelbase_m > 0:
        delta = np.arctan(wheelbase_m * course.curvature)
        d_delta = np.abs(np.roll(delta, -1) - np.roll(delta, 1)) / (2 * course.ds)  # [rad/m]
        v = np.minimum(v, steer_rate_max / np.maximum(d_delta, 1e-9))
    v = np.maximum(v, min(v_min, v_cap))
    a_acc = np.minimum(long_fraction * mu_arr * g, a_drive_max)
    a_brk = long_fraction * mu_arr * g
    n, ds = course.n, course.ds
    # Three laps so the passes wrap around the loop; the middle lap is kept.
    v3 = np.tile(v, 3)
    s3 = np.arange(3 * n) * ds
    # Forward pass with a constant limit per sample (piecewise): v^2(s) <= v^2(s') + 2 a (s - s').
    # Using the smallest limit of the loop keeps the closed form exact and conservative.
    a_f = float(np.min(a_acc))
    a_b = float(np.min(a_brk))
    fwd = 2 * a_f * s3 + np.minimum.accumulate(v3**2 - 2 * a_f * s3)
    v3 = np.sqrt(np.maximum(np.minimum(v3**2, fwd), 0.0))
    rev = s3[::-1]
    bwd = (-2 * a_b * rev + np.minimum.accumulate((v3**2 + 2 * a_b * s3)[::-1]))[::-1]
    v3 = np.sqrt(np.maximum(np.minimum(v3**2, bwd), 0.0))
    v = v3[n : 2 * n]
    v.flags.writeable = False  # SpeedProfile keeps a closed copy of it
    vc = np.append(v, v[0])
    dt = 2 * ds / np.maximum(vc[:-1] + vc[1:], 1e-6)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return SpeedProfile(course, v, t, mu if np.ndim(mu) == 0 else mu_arr.copy())
