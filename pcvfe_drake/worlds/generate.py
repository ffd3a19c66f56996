"""Generated worlds: a random drivable closed course over random terrains, from a seed (no pydrake).

:func:`generate_world` draws, from one seed:

- **a course**: a counter-clockwise loop of 4 to 7 rounded corners (left-turn arcs whose angles
  add up to 360 deg) joined by sides of straights and, on some sides, an S-curve of 1 to 4 waves
  (right and left bends of varied length). Bend radii are drawn within a curvature budget: at
  least ``MIN_RADIUS_FACTOR`` times the vehicle's minimum turning radius and at least the
  course's own minimum, so the chosen vehicle can drive every bend; the sides' lengths are then
  solved so that the loop closes exactly. A loop whose corners all turn left and whose S-curves
  are shallow does not cross itself (the course loader checks it anyway, and a draw that fails
  is drawn again from the same generator);
- **terrains**: 3 to 6 regions (or ``terrains``) that split the loop into stretches of random
  length, as sectors around the loop's centre (a ray from the centre crosses the loop once, so
  each sector holds one stretch), each a distinct shipped texture with a friction drawn from
  ``mu_range``, in a random order along the course;
- **transition strips**: a strip of another texture along each sector boundary.

Lengths scale with the vehicle's wheelbase (the Ford Escort's courses are the unit), so a small
car gets a small world. The same seed, options and vehicle give the same files, byte for byte.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from pcvfe_drake.control.course import (
    CourseSpec,
    Segment,
    build_course,
    check_course_for_vehicle,
    min_turning_radius_m,
)
from pcvfe_drake.vehicle.params import VehicleParams

REFERENCE_WHEELBASE_M = 2.39268
"""Wheelbase of the Ford Escort [m]: the generator's lengths are for it and scale with L."""

MIN_RADIUS_FACTOR = 3.0
"""Bends are at least this many times the vehicle's minimum turning radius (kinematic steering
at a third of its range leaves the rest for tracking corrections)."""

TERRAIN_COUNT = (3, 6)
"""Fewest and most terrain regions of a generated world."""

MU_RANGE = (0.15, 1.0)
"""Default range of the drawn frictions [-]."""

MIN_STRETCH_FRACTION = 0.6
"""Each terrain's stretch of the lap is at least this fraction of an even share."""


@dataclass(frozen=True)
class GeneratedWorld:
    """The two files of a generated world, as text, and facts for the user."""

    world_yaml: str
    course_yaml: str
    lap_m: float
    terrains: list[tuple[str, float]]


def _round(x: float, digits: int = 3) -> float:
    return float(round(float(x), digits))


def _corner_displacement(h: float, radius: float, angle: float) -> np.ndarray:
    """Displacement of a left arc of ``radius`` turning by ``angle`` [rad] from heading ``h``."""
    k = 1.0 / radius
    return np.array(
        [(math.sin(h + angle) - math.sin(h)) / k, -(math.cos(h + angle) - math.cos(h)) / k]
    )


def _draw_course(rng: np.random.Generator, scale: float, r_min: float, name: str) -> CourseSpec:
    """One draw of a closed course (may fail to close with positive sides: returns None)."""
    n = int(rng.integers(4, 8))
    share = rng.dirichlet(np.full(n, 4.0))
    angles = 30.0 + share * (360.0 - 30.0 * n)  # each corner at least 30 deg
    angles = np.array([_round(a) for a in angles[:-1]])
    angles = np.append(angles, _round(360.0 - angles.sum()))
    if np.any(angles > 170.0) or np.any(angles < 20.0):
        return None
    radii = [_round(max(r_min, scale * rng.uniform(8.0, 30.0)), 2) for _ in range(n)]
    heading0 = math.radians(_round(rng.uniform(0.0, 360.0), 1))
    # Sides: optional S-curve (its length is fixed by its waves, radius and angle).
    sides = []
    for _ in range(n):
        if rng.random() < 0.6:
            waves = int(rng.integers(1, 5))
            radius = _round(max(r_min, scale * rng.uniform(10.0, 25.0)), 2)
            a = math.radians(rng.uniform(12.0, 30.0))
            length = _round(4.0 * radius * math.sin(a) * waves, 2)
            sides.append((waves, radius, length, 1.0 if rng.random() < 0.5 else -1.0))
        else:
            sides.append(None)
    min_straight = 6.0 * scale
    fixed = np.array([(s[2] if s else 0.0) + 2 * min_straight for s in sides])
    # Headings of the sides and the displacement of the corners.
    h = heading0
    side_dirs, corners = [], np.zeros(2)
    for i in range(n):
        side_dirs.append((math.cos(h), math.sin(h)))
        a = math.radians(angles[i])
        corners += _corner_displacement(h, radii[i], a)
        h += a
    A = np.array(side_dirs).T  # (2, n)
    target = scale * rng.uniform(10.0, 60.0, n)  # extra straight per side
    # Close the loop: sides j, k absorb the gap (the others keep their drawn extra length).
    best = None
    for j in range(n):
        for k in range(j + 1, n):
            sub = A[:, [j, k]]
            if abs(np.linalg.det(sub)) < 0.3:
                continue
            extra = target.copy()
            others = [i for i in range(n) if i not in (j, k)]
            rhs = -corners - A @ fixed - A[:, others] @ extra[others]
            extra[[j, k]] = np.linalg.solve(sub, rhs)
            if np.all(extra >= 0):
                cost = float(np.abs(extra - target).sum())
                if best is None or cost < best[0]:
                    best = (cost, extra)
    if best is None:
        return None
    extra = best[1]
    segments = []
    for i in range(n):
        straight = 2 * min_straight + extra[i]
        s = sides[i]
        if s is None:
            segments.append(Segment("straight", length_m=_round(straight, 4)))
        else:
            waves, radius, length, sign = s
            first = _round(straight * rng.uniform(0.25, 0.75), 4)
            segments.append(Segment("straight", length_m=first))
            segments.append(
                Segment("scurve", length_m=length, radius_m=radius, angle_deg=sign, waves=waves)
            )
            segments.append(Segment("straight", length_m=_round(straight - first, 4)))
        segments.append(Segment("arc", radius_m=radii[i], angle_deg=float(angles[i])))
    return CourseSpec(
        name=name,
        start_x_m=0.0,
        start_y_m=0.0,
        start_heading_deg=_round(math.degrees(heading0), 1),
        segments=segments,
        smoothing_m=_round(6.0 * scale, 3),
        spacing_m=_round(0.1 * scale, 4),
        half_width_m=_round(3.0 * scale, 3),
        speed_mps=_round(4.75 * math.sqrt(scale), 3),
        closure_tol_m=0.05,
    )


def generate_world(
    seed: int,
    vehicle: VehicleParams,
    *,
    terrains: int | None = None,
    mu_range: tuple[float, float] = MU_RANGE,
    textures: list[str],
    name: str | None = None,
    course_file: str = "",
) -> GeneratedWorld:
    """The world of ``seed`` for ``vehicle`` (see the module docstring). ``textures``: the
    shipped texture names to draw from (at least ``terrains + 1``); ``course_file``: the name
    the world file gives its course file (default ``<name>_course.yaml``)."""
    if not (isinstance(seed, int) and seed >= 0):
        raise ValueError(f"--seed must be an integer >= 0, got {seed!r}")
    lo_k, hi_k = TERRAIN_COUNT
    if terrains is not None and not (isinstance(terrains, int) and lo_k <= terrains <= hi_k):
        raise ValueError(f"--terrains must be an integer in [{lo_k}, {hi_k}], got {terrains!r}")
    lo, hi = (float(v) for v in mu_range)
    if not (0.0 < lo <= hi <= 2.0):
        raise ValueError(f"--mu-range must satisfy 0 < LO <= HI <= 2, got {lo:g} {hi:g}")
    name = name or f"generated_s{seed:04d}"
    course_file = course_file or f"{name}_course.yaml"
    rng = np.random.default_rng([seed, 27])
    k = terrains if terrains is not None else int(rng.integers(lo_k, hi_k + 1))
    if len(textures) < k + 1:
        raise ValueError(f"need {k + 1} textures to draw from, have {len(textures)}")
    scale = vehicle.L / REFERENCE_WHEELBASE_M
    r_min = MIN_RADIUS_FACTOR * min_turning_radius_m(vehicle)
    for _attempt in range(200):
        spec = _draw_course(rng, scale, r_min, name)
        if spec is None:
            continue
        try:
            course = build_course(spec)
            check_course_for_vehicle(course, vehicle, "generated course")
        except ValueError:
            continue
        break
    else:
        raise ValueError(f"seed {seed}: no drivable closed course in 200 draws")
    # Centre the course on the origin (shift the start).
    cx = 0.5 * (course.x.min() + course.x.max())
    cy = 0.5 * (course.y.min() + course.y.max())
    spec.start_x_m = _round(-cx, 3)
    spec.start_y_m = _round(-cy, 3)
    course = build_course(spec)
    margin = 20.0 * scale
    half_w = math.ceil((np.abs(course.x).max() + margin) / 5.0) * 5.0
    half_h = math.ceil((np.abs(course.y).max() + margin) / 5.0) * 5.0
    # Stretches along the lap: k cut points (the first one at a random place).
    share = MIN_STRETCH_FRACTION / k + rng.dirichlet(np.full(k, 3.0)) * (1 - MIN_STRETCH_FRACTION)
    offset = rng.uniform(0.0, 1.0)
    cuts = np.mod(offset + np.concatenate([[0.0], np.cumsum(share)[:-1]]), 1.0) * course.length
    cut_xy = np.column_stack(course.sample(cuts)[:2])
    centre = np.array([np.mean(course.x), np.mean(course.y)])
    theta = np.unwrap(np.arctan2(cut_xy[:, 1] - centre[1], cut_xy[:, 0] - centre[0]))
    order = np.argsort(np.mod(theta - theta[0], 2 * np.pi))
    theta = theta[0] + np.mod(theta[order] - theta[0], 2 * np.pi)
    picked = rng.choice(len(textures), size=k + 1, replace=False)
    names = [textures[int(i)] for i in picked]
    mus = [_round(rng.uniform(lo, hi), 2) for _ in range(k + 1)]
    reach = 2.0 * math.hypot(half_w, half_h)
    regions = []
    for i in range(k):
        a0 = theta[i]
        a1 = theta[i + 1] if i + 1 < k else theta[0] + 2 * np.pi
        arc = np.linspace(a0, a1, max(2, int(math.degrees(a1 - a0) / 5) + 1))
        pts = [centre.tolist()] + [
            [centre[0] + reach * math.cos(a), centre[1] + reach * math.sin(a)] for a in arc
        ]
        regions.append({"terrain": names[i], "polygon": [[_round(x), _round(y)] for x, y in pts]})
    strip_width = _round(max(1.0, 3.0 * scale), 2)
    strips = []
    for i in range(k):
        a = theta[i]
        end = centre + reach * np.array([math.cos(a), math.sin(a)])
        waves = {
            side: [
                {
                    "amplitude_m": _round(strip_width * rng.uniform(0.03, 0.1)),
                    "wavelength_m": _round(rng.uniform(2.0, 9.0) * max(scale, 0.3)),
                    "phase_rad": _round(rng.uniform(0.0, 2 * np.pi)),
                }
                for _ in range(2)
            ]
            for side in ("left_waves", "right_waves")
        }
        strips.append(
            {
                "terrain": names[k],
                "start": [_round(centre[0]), _round(centre[1])],
                "end": [_round(end[0]), _round(end[1])],
                "width_m": strip_width,
                **waves,
            }
        )
    world = {
        "name": name,
        "description": f"generated world, seed {seed}: {k} terrains along a "
        f"{course.length:.0f} m course, transition strips of {names[k]}",
        "bounds_m": [-half_w, half_w, -half_h, half_h],
        "resolution_m": 0.05,
        "course": course_file,
        "terrains": [{"name": n, "texture": n, "mu": m} for n, m in zip(names, mus, strict=True)],
        "regions": regions,
        "strips": strips,
    }
    header = (
        f"# A generated world (pcvfe world generate --seed {seed}); format and generator:\n"
        "# docs/worlds.md.\n"
    )
    world_yaml = header + yaml.safe_dump(world, sort_keys=False, default_flow_style=None, width=100)
    course_dict = spec.to_dict()
    course_yaml = (
        f"# The course of the generated world {name} (docs/worlds.md).\n"
        + yaml.safe_dump(course_dict, sort_keys=False, default_flow_style=None, width=100)
    )
    order_names = [names[i] for i in range(k)]
    return GeneratedWorld(
        world_yaml,
        course_yaml,
        float(course.length),
        [(n, m) for n, m in zip(order_names + [names[k]], mus, strict=True)],
    )


def write_generated_world(
    seed: int,
    vehicle: VehicleParams,
    out_dir: Path,
    *,
    terrains: int | None = None,
    mu_range: tuple[float, float] = MU_RANGE,
    name: str | None = None,
) -> tuple[Path, GeneratedWorld]:
    """Generate the world of ``seed`` with the shipped textures and write its world file and
    course file into ``out_dir``; returns the world file's path and the world. An existing file
    with other content is replaced (the same seed rewrites the same bytes)."""
    from pcvfe_drake.perception.texture_library import default_textures

    name = name or f"generated_s{seed:04d}"
    world = generate_world(
        seed,
        vehicle,
        terrains=terrains,
        mu_range=mu_range,
        textures=default_textures().names,
        name=name,
    )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    world_path = out_dir / f"{name}.yaml"
    for path, text in (
        (out_dir / f"{name}_course.yaml", world.course_yaml),
        (world_path, world.world_yaml),
    ):
        if not path.is_file() or path.read_text() != text:
            path.write_text(text)
    return world_path, world
