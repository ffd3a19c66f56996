"""Loading world files into ``pcvfe_drake.worlds.world_file.WorldSpec`` with ``yaml_load_typed``,
and building a scenario's world (terrain map and course) from them.

The dataclasses, their validation and the raster building live in the core
(``pcvfe_drake/worlds``, no pydrake); the loader lives here because it uses
``pydrake.common.yaml`` (through ``scenario_io.load_typed_yaml``, so a malformed file gets the
same one-line errors naming the file and the dotted field as a scenario).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pcvfe_drake.control.course import Course, check_course_for_vehicle, load_course
from pcvfe_drake.diagrams.scenario_io import read_yaml_file, world_from_yaml_text
from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.worlds.build import apply_overrides, build_terrain_map, check_course_on_world
from pcvfe_drake.worlds.world_file import WorldSpec, resolve_world_path


def load_world(path_or_name: str | Path, relative_to: Path | None = None) -> tuple[WorldSpec, Path]:
    """A world from a shipped name or a file: ``(spec, file)``."""
    path = resolve_world_path(path_or_name, relative_to)
    return world_from_yaml_text(read_yaml_file(path, "world"), str(path)), path


@dataclass
class World:
    """A built world: its spec and file, the terrain raster and the course to drive."""

    spec: WorldSpec
    path: Path
    terrain_map: TerrainMap
    course: Course


def world_course_name(spec: WorldSpec, path: Path) -> str:
    """The world's course as a name or an absolute file ("" when it has none)."""
    if not spec.course:
        return ""
    relative = path.parent / spec.course
    return str(relative.resolve()) if relative.is_file() else spec.course


def build_world(
    path_or_name: str | Path,
    *,
    terrains=None,
    course: str = "",
    vehicle=None,
    source: str | None = None,
    check_course: bool = True,
) -> World:
    """Load and build a world. ``terrains``: a scenario's per-terrain overrides; ``course``
    replaces the world's course ("" keeps it); ``vehicle`` (``VehicleParams``): when given, the
    course must be drivable by it (no bend tighter than its turning radius). ``source`` names
    the caller in errors (default: the world file)."""
    spec, path = load_world(path_or_name)
    where = source or str(path)
    spec = apply_overrides(spec, terrains or {}, where)
    terrain_map = build_terrain_map(spec, path.parent, source=str(path))
    course_name = course or world_course_name(spec, path)
    if not course_name:
        raise ValueError(f"{where}: the world {spec.name!r} ({path}) has no course; name one")
    built = load_course(course_name)
    if check_course:
        check_course_on_world(
            built, terrain_map, f"{where} (world {spec.name}, course {course_name})"
        )
        if vehicle is not None:
            check_course_for_vehicle(built, vehicle, f"{where} (course {course_name})")
    return World(spec, path, terrain_map, built)


def scenario_world(scenario, vehicle=None) -> World:
    """The world a scenario runs in: its ``world`` with its ``terrains`` overrides and, when it
    names one, its own ``course``."""
    return build_world(
        scenario.world,
        terrains=scenario.terrains,
        course=scenario.course,
        vehicle=vehicle,
        source=f"scenario {scenario.name!r}",
    )


def course_to_drive(course: str, world) -> str:
    """The course a run drives: ``course`` when it names one, else the course of ``world`` (a
    shipped name or a file; "" when neither names one)."""
    if course or not world:
        return course or ""
    return world_course_name(*load_world(world))


def scenario_course(scenario) -> Course:
    """The course a scenario drives (its own ``course``, else its world's), without building
    the world's terrain raster."""
    name = course_to_drive(scenario.course, scenario.world)
    if not name:
        raise ValueError(f"scenario {scenario.name!r}: the world {scenario.world!r} has no course")
    return load_course(name)


def world_terrain_map(path_or_name: str | Path) -> TerrainMap:
    """The terrain map of a world (shipped name or file), without its course."""
    spec, path = load_world(path_or_name)
    return build_terrain_map(spec, path.parent, source=str(path))
