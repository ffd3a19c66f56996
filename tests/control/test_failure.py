"""The one definition of a catastrophic failure."""

import math

import numpy as np

from pcvfe_drake.control.failure import (
    NON_FINITE,
    OFF_COURSE,
    SPINNING,
    failure_events,
    failure_kinds,
    failure_reason,
)


def test_kinds_on_the_thresholds():
    lat = np.array([0.0, 2.9, 3.1, 0.0, 0.0, 0.0, 0.0, np.nan])
    cae = np.array([0.0, 0.0, 0.0, math.radians(59), math.radians(61), 2 * math.pi, 0.0, 0.0])
    beta = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, math.radians(31), 0.0])
    kinds = failure_kinds(3.0, lat, cae, beta)
    assert list(kinds) == ["", "", OFF_COURSE, "", SPINNING, "", SPINNING, NON_FINITE]
    assert failure_reason(3.0, 0.5, 0.0, 0.0) == ""
    assert failure_reason(3.0, -4.0, 0.0, 0.0).startswith("left the course: lateral error -4.00")


def test_events_start_on_rising_edges_with_time_and_place():
    t = np.arange(10) * 0.1
    lat = np.array([0, 4, 4, 0, 0, 0, 0, 0, 0, 0], float)
    beta = np.array([0, 0, 0, 0, 0, 1.0, 1.0, 0, 0, 0], float)
    xy = np.column_stack([t * 10, -t])
    ev = failure_events(t, xy, t * 10, 3.0, lat, np.zeros(10), beta, np.ones(10, bool))
    assert [(e.t_s, e.kind) for e in ev] == [(0.1, OFF_COURSE), (0.5, SPINNING)]
    assert ev[1].x_m == 5.0 and ev[1].y_m == -0.5 and ev[1].s_m == 5.0
    d = ev[0].to_dict()
    assert d["detail"] == "left the course: lateral error 4.00 m" and d["kind"] == "off_course"
    assert (d["t_s"], d["sx_m"], d["sy_m"]) == (0.1, 1.0, -0.1)
