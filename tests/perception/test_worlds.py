"""World files: the shipped paper worlds reproduce the old built-in layout cell for cell, and bad
worlds, courses and overrides are one-line errors naming the file and the field."""

from __future__ import annotations

import hashlib
import re
import textwrap

import cv2
import numpy as np
import pytest

from pcvfe_drake.diagrams.world_io import build_world, load_world, world_from_yaml_text
from pcvfe_drake.perception.ground_render import render_topdown
from pcvfe_drake.worlds.build import build_terrain_map
from pcvfe_drake.worlds.world_file import TerrainOverride

# sha256 of the label rasters of the built-in layout (perception/terrain.py's
# default_terrain_map) that the shipped worlds replaced, computed from that code before it was
# removed: strip widths 3 m (paper), 0.6 m (paper_small) and none (paper_no_strips).
OLD_LAYOUT_SHA256 = {
    "paper": "29a009dedfe085cea37ca19c569f3f7fc1159dbfe52d22eb0fb575d2cc1b507a",
    "paper_small": "02a729cccf01e862ae0b73bf556c8cd6a73c64347593359752003c87b8571f2e",
    "paper_no_strips": "c2e0df8b5198802f9a9b0beea6070511574df9a3cbd3818f2daf382d19759d97",
}
OLD_TERRAINS = [
    ("patchy_grass", 0.3),
    ("brick", 0.8),
    ("sand", 0.45),
    ("concrete", 0.6),
    ("dry_soil", 0.5),
    ("gravel", 0.55),
]


@pytest.mark.parametrize("name", sorted(OLD_LAYOUT_SHA256))
def test_shipped_paper_worlds_give_the_old_raster_cell_for_cell(name):
    spec, path = load_world(name)
    m = build_terrain_map(spec, path.parent)
    assert m.labels.shape == (4000, 6000) and m.bounds_m == (-150.0, 150.0, -100.0, 100.0)
    assert hashlib.sha256(m.labels.tobytes()).hexdigest() == OLD_LAYOUT_SHA256[name]
    n = 4 if name == "paper_no_strips" else 6
    assert [(t.name, t.mu) for t in m.terrains] == OLD_TERRAINS[:n]
    assert set(m.transitions) == (set() if n == 4 else {"gravel", "dry_soil"})


SMALL = """
name: small
bounds_m: [-30, 30, -20, 20]
resolution_m: 0.1
course: oval.yaml
terrains:
  - {name: grass, texture: patchy_grass, mu: 0.3}
  - {name: stone, texture: brick, mu: 0.8}
regions:
  - {terrain: grass, polygon: [[-30, -20], [30, -20], [30, 20], [-30, 20]]}
  - {terrain: stone, polygon: [[0, -20], [30, -20], [30, 20], [0, 20]]}
"""

COURSE = """
name: oval
start_x_m: -10.0
start_y_m: -10.0
start_heading_deg: 0.0
smoothing_m: 2.0
half_width_m: 2.0
speed_mps: 4.0
segments:
  - {kind: straight, length_m: 20.0}
  - {kind: arc, radius_m: 10.0, angle_deg: 180.0}
  - {kind: straight, length_m: 20.0}
  - {kind: arc, radius_m: 10.0, angle_deg: 180.0}
"""


def write_world(tmp_path, text=SMALL, course=COURSE):
    (tmp_path / "oval.yaml").write_text(textwrap.dedent(course))
    path = tmp_path / "world.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def test_a_world_written_from_scratch_builds_with_its_course_and_overrides(tmp_path):
    path = write_world(tmp_path)
    world = build_world(path)
    m = world.terrain_map
    assert world.course.name == "oval" and m.transitions == ()
    assert m.name_at(np.array([[-5.0, 0.0], [5.0, 0.0]])).tolist() == ["grass", "stone"]
    changed = build_world(path, terrains={"grass": TerrainOverride(mu=0.22)})
    assert changed.terrain_map.mu_at(np.array([-5.0, 0.0])) == 0.22
    assert changed.terrain_map.mu_at(np.array([5.0, 0.0])) == 0.8


def test_a_label_image_with_a_legend_and_a_photo_texture(tmp_path):
    image = np.zeros((40, 60, 3), np.uint8)
    image[:, :30] = (10, 200, 10)
    image[:, 30:] = (200, 10, 10)
    cv2.imwrite(str(tmp_path / "labels.png"), image[..., ::-1])
    photo = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "photo.png"), photo)
    text = SMALL.split("regions:")[0].replace("texture: brick", "texture: photo.png, tile_m: 1.5")
    text += """
label_image:
  file: labels.png
  legend: {"#0ac80a": grass, "#c80a0a": stone}
"""
    world = build_world(write_world(tmp_path, text))
    m = world.terrain_map
    assert m.name_at(np.array([[-15.0, 5.0], [15.0, -5.0]])).tolist() == ["grass", "stone"]
    assert m.textures.tile_m("photo.png") == 1.5
    top = render_topdown(m, 1.0)
    assert top.shape == (40, 60, 3)
    # The photo's mean colour is what the east half shows (flat rendering).
    flat = render_topdown(m, 1.0, flat=True)
    np.testing.assert_allclose(flat[20, 45], photo[..., ::-1].reshape(-1, 3).mean(0), atol=1)


def test_mu_variation_is_smooth_seeded_and_of_the_given_amplitude(tmp_path):
    text = SMALL.replace(
        "mu: 0.3}", "mu: 0.5, variation: {amplitude: 0.05, length_scale_m: 5.0, seed: 3}}"
    )
    m1 = build_world(write_world(tmp_path, text)).terrain_map
    m2 = build_world(write_world(tmp_path, text)).terrain_map
    x, y = np.meshgrid(np.linspace(-29, -1, 60), np.linspace(-19, 19, 60))
    xy = np.column_stack([x.ravel(), y.ravel()])
    mu = m1.mu_at(xy)
    np.testing.assert_array_equal(mu, m2.mu_at(xy))
    assert 0.02 < mu.std() < 0.08 and abs(mu.mean() - 0.5) < 0.05
    step = np.abs(np.diff(m1.mu_at(np.column_stack([np.linspace(-29, -1, 281), np.zeros(281)]))))
    assert step.max() < 0.01  # smooth: 10 cm steps change mu by little
    assert m1.mu_at(np.array([5.0, 0.0])) == 0.8  # a terrain without variation is uniform
    assert m1.mu_at(xy[7]) == mu[7]


def bad(tmp_path, match, text=SMALL, course=COURSE, **kwargs):
    with pytest.raises(ValueError, match=match) as info:
        build_world(write_world(tmp_path, text, course), **kwargs)
    assert "\n" not in str(info.value)
    return str(info.value)


QUADRANT = "[[0, -20], [30, -20], [30, 20], [0, 20]]"
BAD_WORLDS = [
    (
        (
            "[-30, -20], [30, -20], [30, 20], [-30, 20]",
            "[-30, -20], [-5, -20], [-5, 20], [-30, 20]",
        ),
        "world.yaml .*the regions leave part of course 'oval' on no terrain",
    ),
    (
        ("texture: brick", "texture: marble"),
        r"terrains\[1\].texture='marble': is neither a shipped",
    ),
    (
        ("texture: brick", "texture: nothere.png"),
        r"terrains\[1\].texture='nothere.png': image file .*nothere.png does not exist",
    ),
    (
        ("mu: 0.3", "mu: 2.5"),
        r"world.yaml: invalid world: terrains\[0\].mu=2.5: must be a number in",
    ),
    (("mu: 0.3", "mu: 0"), r"terrains\[0\].mu=0.0: must be a number in \(0, 2\]"),
    ((QUADRANT, "[[0, -20], [30, -20]]"), r"regions\[1\].polygon=.*needs at least 3 points"),
    (
        (QUADRANT, "[[0, -20], [30, 20], [30, -20], [0, 20]]"),
        r"regions\[1\].polygon='4 points': crosses itself",
    ),
    (("{terrain: stone", "{terrain: lava"), r"regions\[1\].terrain='lava': is not one of"),
    (("[-30, 30, -20, 20]", "[-30, 30, -20, 11]"), "course 'oval' leaves the world's bounds near"),
]


@pytest.mark.parametrize("change, match", BAD_WORLDS)
def test_bad_worlds_are_one_line_errors_naming_the_file_and_field(tmp_path, change, match):
    bad(tmp_path, match, SMALL.replace(*change))


def test_an_override_of_a_terrain_the_world_lacks_is_a_named_error(tmp_path):
    match = r"scenario 'x': terrains.ice: the world 'small' has no terrain 'ice' \(its terrains"
    bad(tmp_path, match, terrains={"ice": TerrainOverride(mu=0.1)}, source="scenario 'x'")


def test_label_image_colours_must_be_in_the_legend(tmp_path):
    image = np.zeros((4, 6, 3), np.uint8)
    image[:, 3:] = (1, 2, 3)
    cv2.imwrite(str(tmp_path / "labels.png"), image[..., ::-1])
    text = (
        SMALL.split("regions:")[0] + 'label_image: {file: labels.png, legend: {"#000000": grass}}\n'
    )
    bad(
        tmp_path,
        r"label image .*labels.png: colour #010203 \(12 pixels\) is not in the legend",
        text,
    )


def test_courses_that_cannot_be_driven_are_rejected(tmp_path):
    from pcvfe_drake.vehicle.params import load_vehicle

    big = _vehicle_with_min_radius(load_vehicle("ford_escort"), 12.0)
    match = r"a bend of radius 10.\d+ m .* is tighter than the vehicle 'big' can turn"
    bad(tmp_path, match, vehicle=big)
    loops = "  - {kind: arc, radius_m: 5.0, angle_deg: 360.0}\n" * 2
    crossing = COURSE.split("segments:")[0] + "segments:\n" + loops
    bad(tmp_path, "course 'oval': the course crosses itself", course=crossing)


def _vehicle_with_min_radius(params, radius_m):
    import dataclasses
    import math

    delta = math.atan(params.L / radius_m)
    return dataclasses.replace(params, name="big", delta_max=delta, delta_min=-delta)


BAD_COURSES = [
    (("radius_m: 10.0", "radius_m: twelve"), r"segment 1: radius_m='twelve': must be a number"),
    (("angle_deg: 180.0}", "angle_deg: 180.0, waves: 2.5}"), r"waves=2.5: must be a whole number"),
    (("smoothing_m: 2.0", "smoothing_m: 30.0"), r"smoothing_m=30 is longer than 0.1 of the lap"),
    (("start_x_m: -10.0", "start_x_m: west"), r"start_x_m='west': must be a number"),
    (
        ("length_m: 20.0}", "length_m: 21.0}"),
        r"segments do not close: end is 1.000 m from the start",
    ),
]


@pytest.mark.parametrize("change, match", BAD_COURSES)
def test_course_files_with_bad_values_are_named_errors(tmp_path, change, match):
    msg = bad(tmp_path, match, course=COURSE.replace(*change, 1))
    assert "oval.yaml" in msg


def test_world_yaml_errors_name_the_field(tmp_path):
    with pytest.raises(
        ValueError, match=r"src: malformed world: field 'resolution_m' must be a number"
    ):
        world_from_yaml_text("resolution_m: fine\n", "src")
    with pytest.raises(ValueError, match=r"unknown field 'terrain'"):
        world_from_yaml_text("terrain: []\n", "src")


def test_a_scenario_names_a_world_file_and_overrides_its_frictions(tmp_path):
    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.diagrams.world_io import scenario_world

    write_world(tmp_path)
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text("world: world.yaml\nterrains: {grass: {mu: 0.22}}\n")
    scenario = load_scenario("paper_sim", overlay)
    assert scenario.world == str(tmp_path / "world.yaml")
    world = scenario_world(scenario)
    assert world.terrain_map.mu_at(np.array([-5.0, 0.0])) == 0.22
    assert scenario.to_dict()["terrains"] == {"grass": {"mu": 0.22}}
    overlay.write_text("world: world.yaml\nterrains: {ice: {mu: 0.22}}\n")
    # Checked when the scenario loads, naming the layer that set the field.
    with pytest.raises(ValueError, match=re.escape(f"{overlay}: terrains.ice: the world 'small'")):
        load_scenario("paper_sim", overlay)
    overlay.write_text("terrains: {ice: {mu: -1}}\n")
    with pytest.raises(ValueError, match=r"terrains.ice.mu=-1.0: must be a number in \(0, 2\]"):
        load_scenario("paper_sim", overlay)


def test_the_speed_profile_keeps_the_steering_rate_within_the_limit():
    from pcvfe_drake.control.course import CourseSpec, Segment, build_course
    from pcvfe_drake.control.speed_profile import speed_profile

    waves = [
        Segment("scurve", length_m=60.0, radius_m=8.0, waves=4, angle_deg=1.0),
        Segment("arc", radius_m=10.0, angle_deg=180.0),
    ]
    course = build_course(
        CourseSpec(name="waves", segments=waves * 2, smoothing_m=3.0, speed_mps=8.0)
    )
    wheelbase, rate = 2.4, 0.32
    free = speed_profile(course, 0.9)
    limited = speed_profile(course, 0.9, steer_rate_max=rate, wheelbase_m=wheelbase)
    delta = np.arctan(wheelbase * course.curvature)
    d_delta = np.abs(np.gradient(np.unwrap(delta), course.ds))
    assert np.max(free.v * d_delta) > 1.5 * rate  # friction alone asks for too fast a steering
    assert np.max(limited.v * d_delta) < 1.05 * rate
    assert np.all(limited.v <= free.v + 1e-12) and limited.lap_time > free.lap_time
    off = speed_profile(course, 0.9, steer_rate_max=0.0, wheelbase_m=wheelbase)
    np.testing.assert_array_equal(off.v, free.v)
