"""Courses: construction and closure, projection, progress, speed profiles."""

import math

import numpy as np
import pytest

from pcvfe_drake.control.course import (
    CourseSpec,
    Segment,
    build_course,
    course_names,
    load_course,
    load_course_spec,
)
from pcvfe_drake.control.speed_profile import speed_profile
from pcvfe_drake.vehicle.params import G_MPS2


def circle(radius=10.0, spacing=0.05):
    spec = CourseSpec(
        name="circle",
        start_x_m=0.0,
        start_y_m=-radius,
        segments=[Segment(kind="arc", radius_m=radius, angle_deg=360.0)],
        spacing_m=spacing,
        half_width_m=1.0,
        speed_mps=4.0,
    )
    return build_course(spec)


def test_shipped_courses_listed_and_slalom_is_the_papers_layout():
    assert {"slalom", "slalom_small"} <= set(course_names())
    c = load_course("slalom")
    assert c.turns == 1  # counter-clockwise, one turn
    # ~260 m x 170 m centred at the origin, inside the terrain map (x in [-150, 150],
    # y in [-100, 100]) with the camera's margin
    assert 258 < c.x.max() - c.x.min() < 268
    assert 168 < c.y.max() - c.y.min() < 173
    assert abs(0.5 * (c.x.max() + c.x.min())) < 2.5
    assert abs(0.5 * (c.y.max() + c.y.min())) < 1.0
    assert c.x.max() < 140 and c.x.min() > -140 and np.abs(c.y).max() < 90
    # Two straight sides (zero curvature over >= 2 x 100 m) and S-curves (curvature changes sign).
    straight = np.abs(c.curvature) < 1e-9
    assert straight.sum() * c.ds > 200
    signs = np.sign(c.curvature[np.abs(c.curvature) > 0.05])
    assert np.count_nonzero(np.diff(signs)) >= 26  # 7 waves a side: 2 x 14 sign changes
    # Closed and consistent: the last sample leads smoothly back to the first.
    gap = math.hypot(c.x[0] - c.x[-1], c.y[0] - c.y[-1])
    assert abs(gap - c.ds) < 1e-3
    chord_heading = np.arctan2(np.diff(c.y), np.diff(c.x))
    mid_heading = 0.5 * (c.heading[:-1] + c.heading[1:])
    assert np.max(np.abs(np.angle(np.exp(1j * (chord_heading - mid_heading))))) < 1e-6


def test_each_terrain_gets_40_s_and_the_lap_is_the_papers_length():
    from pcvfe_drake.diagrams.world_io import world_terrain_map

    c = load_course("slalom")
    terrain = world_terrain_map("paper")
    names = terrain.name_at(np.column_stack([c.x, c.y]))
    quadrants = {t.name for t in terrain.terrains if t.name not in ("gravel", "dry_soil")}
    assert len(quadrants) == 4
    for mu in (0.3, 0.45, 0.6, 0.8):
        prof = speed_profile(c, mu)
        assert 170.0 < prof.lap_time < 230.0  # the paper's lap is ~230 s
        dt = np.diff(prof.t)
        for name in quadrants:  # >= 20 s to settle, then >= 20 s scored, in one lap
            assert dt[names == name].sum() >= 40.0
    # The small course also crosses every quadrant for a quarter of its lap.
    small = load_course("slalom_small")
    names = terrain.name_at(np.column_stack([small.x, small.y]))
    dt = np.diff(speed_profile(small, 0.3).t)
    for name in quadrants:
        assert 0.18 < dt[names == name].sum() / dt.sum() < 0.25


def test_small_course_is_the_same_shape_scaled_for_the_roboracer():
    big = load_course_spec("slalom")
    small = load_course_spec("slalom_small")
    # Same primitives in the same order, radii 1/5 of the full course's (same lateral
    # acceleration at speeds scaled by sqrt(1/5)).
    assert [s.kind for s in small.segments] == [s.kind for s in big.segments]
    for a, b in zip(small.segments, big.segments, strict=True):
        assert a.radius_m == pytest.approx(b.radius_m / 5)
        assert np.sign(a.angle_deg) == np.sign(b.angle_deg)
    assert small.speed_mps == pytest.approx(big.speed_mps * math.sqrt(0.2), rel=1e-3)
    # It is the earlier 120 m x 80 m slalom (three waves a side) at 1/5 scale.
    c = load_course("slalom_small")
    assert 23.5 < c.x.max() - c.x.min() < 25 and 15.5 < c.y.max() - c.y.min() < 16.5
    scaled_up = build_course(small.scaled(5.0))
    assert scaled_up.length == pytest.approx(5 * c.length, rel=1e-9)
    assert np.abs(scaled_up.curvature).max() == pytest.approx(
        np.abs(load_course("slalom").curvature).max(), rel=0.05
    )


def test_yaml_round_trip(tmp_path):
    import yaml

    spec = load_course_spec("slalom")
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(spec.to_dict()))
    again = load_course(path)
    ref = load_course("slalom")
    np.testing.assert_allclose(again.x, ref.x)
    np.testing.assert_allclose(again.curvature, ref.curvature)


def test_bad_descriptions_raise_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="do not close"):
        build_course(CourseSpec(segments=[Segment(kind="straight", length_m=10.0)]))
    with pytest.raises(ValueError, match="kind='zigzag'"):
        build_course(CourseSpec(segments=[Segment(kind="zigzag", length_m=10.0)]))
    with pytest.raises(ValueError, match="radius too small"):
        Segment(kind="scurve", length_m=100.0, radius_m=1.0).arcs()
    with pytest.raises(ValueError, match="neither a shipped course"):
        load_course("no_such_course")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nwheels: 4\n")
    with pytest.raises(ValueError, match="unknown course field"):
        load_course(bad)


def test_scurve_returns_to_its_line_and_heading():
    spec = CourseSpec(segments=[Segment(kind="scurve", length_m=30.0, radius_m=5.0, waves=2)])
    pieces = spec.segments[0].arcs()
    x = y = h = 0.0
    for ln, k in pieces:
        h2 = h + k * ln
        x, y = x + (math.sin(h2) - math.sin(h)) / k, y - (math.cos(h2) - math.cos(h)) / k
        h = h2
    assert (x, y, h) == pytest.approx((30.0, 0.0, 0.0), abs=1e-9)


def test_projection_on_a_circle_matches_geometry():
    r = 10.0
    c = circle(r)
    assert c.length == pytest.approx(2 * math.pi * r)
    ang = np.array([0.3, 1.7, 4.0])  # polar angle around the centre (0, 0)
    dist = np.array([9.5, 10.8, 10.0])
    xy = np.column_stack([dist * np.cos(ang), dist * np.sin(ang)])
    heading = ang + math.pi / 2 + np.array([0.1, -0.2, 0.0])
    p = c.project(xy, heading=heading)
    # Start at (0, -r) (polar angle -pi/2), counter-clockwise: s = r (angle + pi/2).
    np.testing.assert_allclose(p.s, c.wrap_s(r * (ang + math.pi / 2)), atol=1e-3)
    np.testing.assert_allclose(p.lateral_error, r - dist, atol=1e-4)  # inside = left = +
    np.testing.assert_allclose(p.heading_error, [0.1, -0.2, 0.0], atol=1e-3)
    np.testing.assert_allclose(p.curvature, 1 / r, rtol=1e-6)
    # Vectorised equals one-by-one; a hinted local search gives the same answer.
    for i in range(3):
        one = c.project(xy[i], heading=heading[i])
        assert float(one.s) == pytest.approx(p.s[i])
    hinted = c.project(xy, s_hint=p.s + 0.7, window_m=2.0)
    np.testing.assert_allclose(hinted.s, p.s, atol=1e-9)
    with pytest.raises(ValueError, match="xy"):
        c.project(np.array([np.nan, 0.0]))


def test_progress_counts_laps():
    c = circle(5.0)
    s_true = np.linspace(0.0, 2.5 * c.length, 400)
    progress = c.unwrap_progress(c.wrap_s(s_true))
    np.testing.assert_allclose(progress, s_true, atol=1e-9)
    assert math.floor((progress[-1] - progress[0]) / c.length) == 2


def test_speed_profile_respects_friction_and_acceleration_limits():
    c = load_course("slalom")
    lo = speed_profile(c, 0.3, v_max=12.0)
    hi = speed_profile(c, 0.8, v_max=12.0)
    for prof, mu in ((lo, 0.3), (hi, 0.8)):
        k = np.abs(c.curvature)
        assert np.all(prof.v**2 * k <= 0.8**2 * mu * G_MPS2 + 1e-9)
        dv2 = np.diff(np.append(prof.v, prof.v[0]) ** 2) / (2 * c.ds)
        assert np.all(np.abs(dv2) <= 0.5 * mu * G_MPS2 + 1e-6)
        assert prof.v.max() <= 12.0
    assert np.all(lo.v <= hi.v + 1e-12) and lo.lap_time > hi.lap_time
    # On the straights, far from curves, the cap is reached.
    assert hi.v.max() == pytest.approx(12.0)
    # The time parametrisation advances consistently.
    s0 = 354.0  # middle of the eastern straight, at the cap
    s = lo.advance(s0, [0.0, 1.0, lo.lap_time])
    assert s[0] == pytest.approx(s0)
    assert s[1] - s[0] == pytest.approx(lo.speed_at(s0), rel=0.05)
    assert s[2] - s[0] == pytest.approx(c.length, rel=1e-6)
    with pytest.raises(ValueError, match="mu"):
        speed_profile(c, -0.1)


def test_speed_at_interpolates_the_closed_profile_kept_from_the_first_call():
    # speed_at keeps the closed copy of v (first sample repeated) from its first call; v is
    # read-only, so the copy cannot go stale.
    c = load_course("slalom")
    prof = speed_profile(c, 0.5, v_max=12.0)
    rng = np.random.default_rng(2)
    s = np.concatenate([rng.uniform(-c.length, 2 * c.length, 300), [0.0, c.length, -1e-9]])
    i, t = c.segment_at(s)
    vc = np.append(prof.v, prof.v[0])
    want = vc[i] + t * (vc[i + 1] - vc[i])
    for _ in range(2):
        assert np.array_equal(prof.speed_at(s), want)
        assert prof.speed_at(s[5]) == want[5]
    with pytest.raises(ValueError, match="read-only"):
        prof.v[0] = 1.0
