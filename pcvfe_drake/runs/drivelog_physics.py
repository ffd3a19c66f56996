"""Physics checks of a drive log: samples no car can produce, and columns that contradict each
other in sign or unit (documented with their derivations in ``docs/drive_log.md``).

Single samples (a step from row i-1 to row i that no vehicle can make, at v >= 1 m/s):

* side slip: ``beta' = (F_yf + F_yr) / (m v) - psi_dot`` and ``|F_yf + F_yr| <= mu m g``, so
  ``|beta_i - beta_{i-1}| <= (MU_MAX g / v + |psi_dot|) dt + BETA_STEP_TOL_RAD``;
* yaw rate: ``I_z psi'' = l_f F_yf - l_r F_yr``, so ``|psi''| <= mu m g l / I_z``; with
  ``MAX_YAW_ACCEL_RADPS2`` a generous bound for road vehicles,
  ``|psi_dot_i - psi_dot_{i-1}| <= MAX_YAW_ACCEL_RADPS2 dt + PSI_DOT_STEP_TOL_RADPS``;
* steering angle: ``|delta_i - delta_{i-1}| <= max_steer_rate dt + DELTA_STEP_TOL_RAD`` (the
  drive log's largest plausible steering rate, 7 rad/s).

Consistency of the whole log (each needs enough moving, turning samples to say anything):

* steering and yaw rate: a car moving forward turns the way it steers (``psi_dot ~ v delta /
  l``); fewer than ``MIN_STEER_YAW_AGREEMENT`` of the turning samples agreeing in sign means
  opposite sign conventions;
* heading and travel: the velocity of the centre of gravity points at ``psi + beta`` (the
  definition of the side slip), so the direction of travel from sx, sy over ``COURSE_SPAN_S``
  minus ``psi + beta`` has a median near 0; more than ``MAX_HEADING_OFFSET_RAD`` is a heading bias
  or another zero direction;
* side slip against that slip: the slope of ``course - psi`` on ``beta`` is ~1; a negative or
  tiny slope is a flipped sign or degrees;
* steering rate: ``delta' = steer_rate`` (the model's input), so the change of delta over
  ``COURSE_SPAN_S`` regressed on the integrated steer_rate has slope ~1.
"""

from __future__ import annotations

import math

import numpy as np

G_MPS2 = 9.81
MU_MAX = 3.0
"""Largest friction coefficient the bounds allow (drivelog.MAX_MU_TRUE)."""
V_CHECK_MIN_MPS = 1.0
"""The single-sample checks apply where both samples move at least this fast (slip and its
rate are undefined near standstill)."""
BETA_STEP_TOL_RAD = 0.05
"""Allowance for measurement noise on a side-slip step (10 x a slip sensor's 0.005 rad)."""
MAX_YAW_ACCEL_RADPS2 = 50.0
"""Yaw acceleration bound: mu g l m / I_z is ~10 rad/s^2 for a passenger car at mu = 1
(Ford Escort: 1225 kg, l ~ 1.2 m, I_z ~ 1538 kg m^2); 50 leaves a 5x margin for any road vehicle
up to mu = 3 and short wheelbases."""
PSI_DOT_STEP_TOL_RADPS = 0.1
"""Allowance for gyro noise on a yaw-rate step (10 x 0.01 rad/s)."""
DELTA_STEP_TOL_RAD = 0.02
"""Allowance for encoder noise on a steering-angle step (10 x 0.002 rad)."""
MIN_STEER_YAW_AGREEMENT = 0.5
"""Least fraction of turning samples whose delta and psi_dot agree in sign."""
COURSE_SPAN_S = 0.2
"""Time span of the differences that give the direction of travel and the steering change."""
MAX_HEADING_OFFSET_RAD = 0.15
"""Largest median offset between psi + beta and the direction of travel (8.6 deg)."""
_MIN_SAMPLES = 50


def _step_rows(
    name: str, x: np.ndarray, limit: np.ndarray, ok: np.ndarray, unit: str, why: str, rows_fn
) -> str | None:
    jump = np.abs(np.diff(x))
    with np.errstate(invalid="ignore"):
        bad = np.flatnonzero(ok & (jump > limit)) + 1
    if bad.size == 0:
        return None
    worst = int(bad[np.argmax(jump[bad - 1] - limit[bad - 1])])
    return (
        f"column '{name}': physically impossible step at {rows_fn(bad)} (e.g. row {worst}: "
        f"{x[worst - 1]:.4g} -> {x[worst]:.4g} {unit} in one sample; {why}); a corrupt sample "
        "or a wrong unit: fix or drop those rows"
    )


def single_sample_checks(
    cols: dict, problems: list[str], rows_fn, max_steer_rate_radps: float
) -> None:
    """Steps between consecutive rows that exceed what tire forces allow (see module doc);
    ``rows_fn`` formats row lists for messages."""
    t, v, beta, r, delta = (cols.get(k) for k in ("t", "v", "beta", "psi_dot", "delta"))
    if t is None or v is None or t.size < 2:
        return
    dt = np.diff(t)
    with np.errstate(invalid="ignore"):
        moving = (dt > 0) & (np.minimum(np.abs(v[1:]), np.abs(v[:-1])) >= V_CHECK_MIN_MPS)
    if beta is not None and r is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            v_min = np.maximum(np.minimum(np.abs(v[1:]), np.abs(v[:-1])), V_CHECK_MIN_MPS)
            rate = MU_MAX * G_MPS2 / v_min + np.maximum(np.abs(r[1:]), np.abs(r[:-1]))
        problem = _step_rows(
            "beta",
            beta,
            rate * dt + BETA_STEP_TOL_RAD,
            moving,
            "rad",
            f"tire forces up to {MU_MAX:g} g change the side slip by at most "
            "(mu g / v + |psi_dot|) dt",
            rows_fn,
        )
        if problem:
            problems.append(problem)
    if r is not None:
        problem = _step_rows(
            "psi_dot",
            r,
            MAX_YAW_ACCEL_RADPS2 * dt + PSI_DOT_STEP_TOL_RADPS,
            moving,
            "rad/s",
            f"yaw acceleration beyond {MAX_YAW_ACCEL_RADPS2:g} rad/s^2",
            rows_fn,
        )
        if problem:
            problems.append(problem)
    if delta is not None:
        problem = _step_rows(
            "delta",
            delta,
            max_steer_rate_radps * dt + DELTA_STEP_TOL_RAD,
            moving,
            "rad",
            f"steering faster than {max_steer_rate_radps:g} rad/s",
            rows_fn,
        )
        if problem:
            problems.append(problem)


def span_steps(t: np.ndarray, seconds: float = 0.2) -> int:
    """Rows spanning about ``seconds`` at the median step of ``t`` (at least 1): differences
    over this span are not dominated by measurement noise."""
    steps = np.diff(t)
    steps = steps[np.isfinite(steps) & (steps > 0)]
    if steps.size == 0:
        return 1
    return max(1, int(round(seconds / float(np.median(steps)))))


def _slope(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of y on x through the origin, and the correlation coefficient."""
    sxx, syy, sxy = float(x @ x), float(y @ y), float(x @ y)
    if sxx <= 0 or syy <= 0:
        return math.nan, 0.0
    return sxy / sxx, sxy / math.sqrt(sxx * syy)


def consistency_checks(cols: dict, problems: list[str]) -> None:
    """Signs and units that contradict the physics (see module doc)."""
    t, sx, sy, v = (cols.get(k) for k in ("t", "sx", "sy", "v"))
    delta, r, psi, beta = (cols.get(k) for k in ("delta", "psi_dot", "psi", "beta"))
    steer_rate = cols.get("steer_rate")
    if t is None or v is None or t.size < _MIN_SAMPLES:
        return
    with np.errstate(invalid="ignore"):
        fast = np.isfinite(v) & (v >= 3.0)
        if delta is not None and r is not None:
            turning = fast & (np.abs(delta) > 0.02) & (np.abs(r) > 0.05)
            if turning.sum() >= _MIN_SAMPLES:
                agree = float(np.mean(np.sign(delta[turning]) == np.sign(r[turning])))
                if agree < MIN_STEER_YAW_AGREEMENT:
                    problems.append(
                        f"columns 'delta', 'psi_dot': the car turns against its steering in "
                        f"{1 - agree:.0%} of {int(turning.sum())} turning samples at v >= 3 m/s "
                        "(a forward-moving car turns the way it steers, psi_dot ~ v delta / l); "
                        "opposite sign conventions? flip the sign of delta or of psi_dot"
                    )
    k = span_steps(t, COURSE_SPAN_S)
    if t.size <= k + _MIN_SAMPLES:
        return
    if sx is not None and sy is not None and psi is not None and beta is not None:
        dx, dy = sx[k:] - sx[:-k], sy[k:] - sy[:-k]
        with np.errstate(invalid="ignore"):
            use = fast[k:] & fast[:-k] & (np.hypot(dx, dy) > 0.5)
        mid = np.arange(k, t.size) - k // 2
        use &= np.isfinite(psi[mid]) & np.isfinite(beta[mid])
        if use.sum() >= _MIN_SAMPLES:
            course = np.arctan2(dy[use], dx[use])
            slip = np.angle(np.exp(1j * (course - psi[mid][use])))
            offset = float(np.median(np.angle(np.exp(1j * (slip - beta[mid][use])))))
            if abs(offset) > MAX_HEADING_OFFSET_RAD:
                problems.append(
                    f"column 'psi': psi + beta differs from the direction of travel (from sx, sy) "
                    f"by a median {offset:.3g} rad ({math.degrees(offset):.1f} deg; expected ~0, "
                    "the side slip is the angle between heading and travel); a heading bias, "
                    "another zero direction (north vs east) or swapped sx/sy?"
                )
            b = beta[mid][use]
            if float(np.std(b)) > 0.01:
                slope, corr = _slope(b - np.median(b), slip - np.median(slip))
                if slope < 0 and corr < -0.5:
                    problems.append(
                        f"column 'beta': beta has the opposite sign of the slip between heading "
                        f"and travel (slope {slope:.2g}, correlation {corr:.2f}); flip its sign"
                    )
                elif 0 < slope < 0.05 and corr > 0.5:
                    problems.append(
                        f"column 'beta': beta is {1 / slope:.3g} times the slip between heading "
                        "and travel (expected ~1); beta in degrees?"
                    )
    if delta is not None and steer_rate is not None:
        dt = t[k:] - t[:-k]
        integ = np.concatenate([[0.0], np.cumsum(steer_rate[:-1] * np.diff(t))])
        driven = integ[k:] - integ[:-k]
        change = delta[k:] - delta[:-k]
        with np.errstate(invalid="ignore"):
            use = np.isfinite(driven) & np.isfinite(change) & (dt > 0) & fast[k:]
        if use.sum() >= _MIN_SAMPLES and float(np.std(driven[use])) > 0.01:
            slope, corr = _slope(driven[use], change[use])
            if (slope < 0 and corr < -0.5) or (0 < slope < 0.05 and corr > 0.5):
                hint = "opposite signs?" if slope < 0 else "steer_rate in deg/s?"
                problems.append(
                    f"column 'steer_rate': delta changes {slope:.3g} times as much as steer_rate "
                    f"integrates to (expected ~1, delta' = steer_rate; correlation {corr:.2f}); "
                    f"{hint}"
                )
