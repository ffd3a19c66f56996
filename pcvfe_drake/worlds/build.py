"""Building a world: its terrain raster, its course and the checks that tie them (no pydrake).

:func:`build_terrain_map` paints a :class:`~pcvfe_drake.worlds.world_file.WorldSpec` into a
``TerrainMap``: the label image first, then the regions, then the strips, each covering what
was painted before (a cell belongs to a shape when its centre does). A scenario's terrain
overrides change the frictions on top of the world's. :func:`check_course_on_world` rejects a
course that leaves the bounds or runs over cells no region covers.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from pcvfe_drake.perception.terrain import UNKNOWN, MuField, Terrain, TerrainMap, paint_polygon
from pcvfe_drake.worlds.world_file import (
    StripSpec,
    TerrainOverride,
    WorldSpec,
    mu_problem,
    parse_colour,
)

DEFAULT_PHOTO_TILE_M = 2.0
"""World size of one tile of an image-file texture whose terrain gives no ``tile_m`` [m]."""


def apply_overrides(
    world: WorldSpec, overrides: Mapping[str, TerrainOverride], source: str = "scenario"
) -> WorldSpec:
    """A copy of ``world`` with a scenario's per-terrain overrides applied; an override of a
    terrain the world does not have, or a bad mu, is a ``ValueError`` naming ``source``."""
    if not overrides:
        return world
    names = world.terrain_names()
    terrains = list(world.terrains)
    for name, change in overrides.items():
        if name not in names:
            raise ValueError(
                f"{source}: terrains.{name}: the world {world.name!r} has no terrain {name!r} "
                f"(its terrains: {', '.join(names)})"
            )
        if change.mu is not None:
            why = mu_problem(change.mu)
            if why:
                raise ValueError(f"{source}: terrains.{name}.mu={change.mu!r}: {why}")
            k = names.index(name)
            terrains[k] = dataclasses.replace(terrains[k], mu=float(change.mu))
    return dataclasses.replace(world, terrains=terrains)


def strip_polygon(strip: StripSpec) -> np.ndarray:
    """The (M, 2) outline [m] of a transition strip: its right edge from start to end, then its
    left edge back, each offset across the strip by half the width plus its waves. Where the
    waves cross the edges over (wider waves than the strip) the strip has no width: the left
    edge is held on the right one there, so the outline never folds over itself."""
    a = np.asarray(strip.start, dtype=float)
    b = np.asarray(strip.end, dtype=float)
    length = float(np.hypot(*(b - a)))
    d = (b - a) / length
    n = np.array([-d[1], d[0]])  # left of the direction start -> end
    mid = 0.5 * (a + b)
    s = np.linspace(-length / 2, length / 2, int(length / strip.sample_m) + 1)
    half = 0.5 * strip.width_m
    right = -half + _waves(s, strip.right_waves)
    left = half + _waves(s, strip.left_waves)
    gap = left - right
    cross = np.flatnonzero(np.sign(gap[:-1]) * np.sign(gap[1:]) < 0)
    if cross.size:  # insert the points where the edges meet, then clamp
        t = gap[cross] / (gap[cross] - gap[cross + 1])
        s_new = s[cross] + t * (s[cross + 1] - s[cross])
        r_new = right[cross] + t * (right[cross + 1] - right[cross])
        s = np.insert(s, cross + 1, s_new)
        right = np.insert(right, cross + 1, r_new)
        left = np.insert(left, cross + 1, r_new)
    left = np.maximum(left, right)
    along = mid + s[:, None] * d
    right_xy = along + right[:, None] * n
    left_xy = along + left[:, None] * n
    return np.concatenate([right_xy, left_xy[::-1]])


def _waves(s: np.ndarray, waves) -> np.ndarray:
    total = np.zeros_like(s)
    for k, w in enumerate(waves):
        term = w.amplitude_m * np.sin(2 * np.pi * s / w.wavelength_m + w.phase_rad)
        total = term if k == 0 else total + term
    return total


def texture_problem(texture: str, base_dir: Path | None, shipped: set[str]) -> str:
    """Why ``texture`` names neither a shipped texture nor an image file ("" when it does)."""
    if texture in shipped:
        return ""
    path = Path(texture).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    if path.suffix.lower() not in (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"):
        return f"is neither a shipped texture ({', '.join(sorted(shipped))}) nor an image file"
    if not path.is_file():
        return f"image file {path} does not exist"
    return ""


def build_terrain_map(
    world: WorldSpec,
    base_dir: Path | None = None,
    *,
    source: str = "world",
    textures=None,
) -> TerrainMap:
    """The world's ``TerrainMap`` (label indices in the order of ``world.terrains``). File
    references (texture images, the label image) are relative to ``base_dir``. Errors are one
    line naming ``source`` and the field. ``textures``: the shipped ``TextureSet`` (default: the
    packaged one)."""
    from pcvfe_drake.perception.texture_library import default_textures, load_rgb

    textures = textures if textures is not None else default_textures()
    shipped = set(textures.names)
    files: dict[str, tuple[Path, float]] = {}
    for i, t in enumerate(world.terrains):
        why = texture_problem(t.texture, base_dir, shipped)
        if why:
            raise ValueError(f"{source}: terrains[{i}].texture={t.texture!r}: {why}")
        if t.texture not in shipped:
            path = Path(t.texture).expanduser()
            path = path if path.is_absolute() or base_dir is None else base_dir / path
            files[t.texture] = (path, t.tile_m or DEFAULT_PHOTO_TILE_M)
    x0, x1, y0, y1 = (float(v) for v in world.bounds_m)
    res = float(world.resolution_m)
    cols, rows = int(round((x1 - x0) / res)), int(round((y1 - y0) / res))
    labels = np.full((rows, cols), UNKNOWN, dtype=np.uint8)
    index = {t.name: k for k, t in enumerate(world.terrains)}
    if world.label_image is not None:
        path = Path(world.label_image.file).expanduser()
        path = path if path.is_absolute() or base_dir is None else base_dir / path
        try:
            rgb = load_rgb(path)
        except (FileNotFoundError, ValueError) as exc:
            raise ValueError(f"{source}: label_image.file: {exc}") from exc
        labels[:] = _label_image_labels(rgb, world.label_image.legend, index, (rows, cols), path)
    for region in world.regions:
        paint_polygon(labels, np.asarray(region.polygon, float), index[region.terrain], x0, y1, res)
    for strip in world.strips:
        paint_polygon(labels, strip_polygon(strip), index[strip.terrain], x0, y1, res)
    terrains = [Terrain(t.name, float(t.mu), t.texture) for t in world.terrains]
    fields = [
        MuField.gaussian(
            (x0, x1, y0, y1),
            amplitude=t.variation.amplitude,
            length_scale_m=t.variation.length_scale_m,
            seed=t.variation.seed * 1000 + k,
        )
        if t.variation is not None and t.variation.amplitude > 0
        else None
        for k, t in enumerate(world.terrains)
    ]
    return TerrainMap(
        labels,
        terrains,
        x_min_m=x0,
        y_min_m=y0,
        resolution_m=res,
        mu_fields=fields,
        textures=textures.with_files(files) if files else None,
        transitions=world.transition_terrains(),
    )


def _label_image_labels(
    rgb: np.ndarray, legend: Mapping[str, str], index: dict[str, int], shape, path: Path
) -> np.ndarray:
    """Terrain labels of a legend-coloured image, resized (nearest) to the raster ``shape``."""
    import cv2

    code = (rgb[..., 0].astype(np.int32) << 16) | (rgb[..., 1].astype(np.int32) << 8) | rgb[..., 2]
    lut_codes, inverse = np.unique(code.ravel(), return_inverse=True)
    by_code = {}
    for colour, name in legend.items():
        r, g, b = parse_colour(colour)
        by_code[(r << 16) | (g << 8) | b] = index[name]
    missing = [int(c) for c in lut_codes if int(c) not in by_code]
    if missing:
        c = missing[0]
        count = int(np.count_nonzero(code == c))
        raise ValueError(
            f"label image {path}: colour #{c:06x} ({count} pixels) is not in the legend "
            f"(legend: {', '.join(sorted(legend))})"
        )
    small = np.array([by_code[int(c)] for c in lut_codes], dtype=np.uint8)[inverse]
    small = small.reshape(code.shape)
    rows, cols = shape
    return cv2.resize(small, (cols, rows), interpolation=cv2.INTER_NEAREST)


def check_course_on_world(course, terrain_map: TerrainMap, source: str) -> None:
    """A ``ValueError`` naming ``source`` when the course (its corridor of ``half_width``) leaves
    the map's bounds or its centre line runs over a cell no region covers."""
    x0, x1, y0, y1 = terrain_map.bounds_m
    hw = course.half_width
    out = (course.x - hw < x0) | (course.x + hw > x1) | (course.y - hw < y0) | (course.y + hw > y1)
    if np.any(out):
        i = int(np.flatnonzero(out)[0])
        raise ValueError(
            f"{source}: course {course.name!r} leaves the world's bounds near "
            f"s={course.s[i]:.1f} m ({course.x[i]:.1f}, {course.y[i]:.1f}) "
            f"(bounds x [{x0:g}, {x1:g}], y [{y0:g}, {y1:g}] m, course half width {hw:g} m)"
        )
    row, col = terrain_map.world_to_cell(np.column_stack([course.x, course.y]))
    labels = terrain_map.labels[row.astype(int), col.astype(int)]
    bare = labels == UNKNOWN
    if np.any(bare):
        i = int(np.flatnonzero(bare)[0])
        raise ValueError(
            f"{source}: the regions leave part of course {course.name!r} on no terrain "
            f"({np.count_nonzero(bare) * course.ds:.1f} m of it, first at s={course.s[i]:.1f} m, "
            f"({course.x[i]:.1f}, {course.y[i]:.1f}))"
        )
