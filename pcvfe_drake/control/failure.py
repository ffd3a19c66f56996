"""The one definition of a catastrophic failure, shared by the run summary and the NMPC's loop.

A state of the car is a **catastrophic failure** when any of these holds:

* ``non_finite``: a state entry is NaN or infinite (the simulation broke down);
* ``off_course``: the distance to the reference path exceeds the course's ``half_width``
  (3 m on the shipped courses: the car is off the track);
* ``spin``: the side-slip angle ``|beta|`` exceeds :data:`SPIN_BETA_RAD` (30 deg), or the
  course angle (direction of travel, ``psi + beta``) deviates from the path heading by more
  than :data:`SPIN_COURSE_ANGLE_RAD` (60 deg): the car slides sideways or has turned away;
* ``truth_singular``: the simulated truth cannot be integrated any further: the multi-body
  model's own singularity, a wheel's ground speed at or below zero while the car moves (it
  reverses or has spun; ``pcvfe_drake.vehicle.mb_truth``, "Where the model ends"). No logged
  state shows it (the plant stops before the next row), so the run loop records it as the run's
  last event (:func:`truth_singular_event`) and the run ends there.

A failure *event* starts where the flag rises (``failure_events``); the run summary counts
events, the closed loop (``pcvfe simulate`` with ``stop_on_failure``) ends at the first one and
records its time, place and reason. Plain numpy, no pydrake.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pcvfe_drake.json_numbers import finite_or_none

SPIN_BETA_RAD = math.radians(30.0)
"""Side-slip angle beyond which the car counts as spinning [rad]."""
SPIN_COURSE_ANGLE_RAD = math.radians(60.0)
"""Course-angle error (``psi + beta`` vs the path heading) beyond which the car counts as spinning
or turned away [rad]."""

NON_FINITE, OFF_COURSE, SPINNING = "non_finite", "off_course", "spin"
TRUTH_SINGULAR = "truth_singular"
"""The kinds of failure (codes stored in ``summary.json``)."""
_TEXT = {
    NON_FINITE: "non-finite state",
    OFF_COURSE: "left the course",
    SPINNING: "spinning",
    TRUTH_SINGULAR: "truth model singular",
}


@dataclass(frozen=True)
class FailureEvent:
    """One catastrophic failure: when [s], where (``x_m``, ``y_m``, arc length ``s_m`` along the
    course, or NaN) and why (``kind``: one of the codes, ``detail``: the numbers)."""

    t_s: float
    x_m: float
    y_m: float
    s_m: float
    kind: str
    detail: str

    def to_dict(self) -> dict:
        return {
            "t_s": finite_or_none(self.t_s),
            "sx_m": finite_or_none(self.x_m),
            "sy_m": finite_or_none(self.y_m),
            "s_m": finite_or_none(self.s_m),
            "kind": self.kind,
            "detail": self.detail,
        }


def _wrap(angle):
    return np.angle(np.exp(1j * np.asarray(angle, dtype=float)))


def failure_kinds(
    half_width_m: float, lateral_error_m, course_angle_error_rad, beta_rad, finite=None
) -> np.ndarray:
    """Per sample the failure kind ("" where none): arrays of equal shape in, strings out.

    ``course_angle_error_rad`` is the direction of travel minus the path heading (wrapped here);
    ``finite`` (optional bool array) marks samples whose whole state is finite.
    """
    lat = np.asarray(lateral_error_m, dtype=float)
    cae = _wrap(np.nan_to_num(np.asarray(course_angle_error_rad, dtype=float), nan=0.0))
    beta = np.asarray(beta_rad, dtype=float)
    ok = np.isfinite(lat) & np.isfinite(beta)
    if finite is not None:
        ok &= np.asarray(finite, dtype=bool)
    out = np.full(lat.shape, "", dtype=object)
    spin = ok & ((np.abs(beta) > SPIN_BETA_RAD) | (np.abs(cae) > SPIN_COURSE_ANGLE_RAD))
    off = ok & (np.abs(lat) > half_width_m)
    out[spin] = SPINNING
    out[off] = OFF_COURSE
    out[~ok] = NON_FINITE
    return out


def failure_reason(
    half_width_m: float, lateral_error_m: float, course_angle_error_rad: float, beta_rad: float
) -> str:
    """Why one state counts as failed, with its numbers ("" if it does not)."""
    kind = failure_kinds(half_width_m, [lateral_error_m], [course_angle_error_rad], [beta_rad])[0]
    return _detail(kind, lateral_error_m, course_angle_error_rad, beta_rad)


def _detail(kind: str, lat: float, cae: float, beta: float) -> str:
    if kind == OFF_COURSE:
        return f"{_TEXT[kind]}: lateral error {lat:.2f} m"
    if kind == SPINNING:
        return f"{_TEXT[kind]}: course-angle error {float(_wrap(cae)):.2f} rad, beta {beta:.2f} rad"
    if kind == NON_FINITE:
        return _TEXT[kind]
    return ""


def failure_events(
    t_s, xy_m, s_m, half_width_m: float, lateral_error_m, course_angle_error_rad, beta_rad, finite
) -> list[FailureEvent]:
    """The failure events of a run: one per rising edge of the failure flag, in time order; the
    place is the last finite position at or before the event."""
    kinds = failure_kinds(half_width_m, lateral_error_m, course_angle_error_rad, beta_rad, finite)
    failed = kinds != ""
    starts = np.flatnonzero(failed & ~np.concatenate([[False], failed[:-1]]))
    t = np.asarray(t_s, dtype=float)
    xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    s = np.asarray(s_m, dtype=float)
    lat = np.asarray(lateral_error_m, dtype=float)
    cae = np.asarray(course_angle_error_rad, dtype=float)
    beta = np.asarray(beta_rad, dtype=float)
    finite_rows = np.flatnonzero(np.all(np.isfinite(xy), axis=1))
    events = []
    for i in starts:
        before = finite_rows[finite_rows <= i]  # the place: the last finite position
        j = int(before[-1]) if before.size else i
        events.append(
            FailureEvent(
                float(t[i]),
                float(xy[j, 0]),
                float(xy[j, 1]),
                float(s[j]),
                str(kinds[i]),
                _detail(kinds[i], float(lat[i]), float(cae[i]), float(beta[i])),
            )
        )
    return events


def truth_singular_event(t_s: float, x_m: float, y_m: float, s_m: float, detail: str):
    """The failure event of a run whose truth could no longer be integrated (``truth_singular``)
    at time ``t_s`` [s] and place (``x_m``, ``y_m``; ``s_m`` along the course, NaN without one);
    ``detail`` says why (the wheels' ground speeds)."""
    return FailureEvent(
        float(t_s),
        float(x_m),
        float(y_m),
        float(s_m),
        TRUTH_SINGULAR,
        f"{_TEXT[TRUTH_SINGULAR]}: {detail}",
    )
