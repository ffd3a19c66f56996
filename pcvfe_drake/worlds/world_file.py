"""The world file: what lies where, how slippery it is and which course crosses it (no pydrake).

A world is a YAML file loaded into :class:`WorldSpec` with ``pydrake.common.yaml.yaml_load_typed``
by ``pcvfe_drake.diagrams.world_io`` (the core never imports pydrake, so the loader lives with
the diagrams). Like the scenario module, this one does not use ``from __future__ import
annotations``: ``yaml_load_typed`` reads real types from the fields.

What a world holds (docs/worlds.md explains every field with an example):

- ``bounds_m`` and ``resolution_m``: the raster of terrain labels every look-up reads (the car's
  friction, the camera's ground image, the figures);
- ``terrains``: name, texture (a shipped texture name or an image file, relative to the world
  file), friction ``mu`` and an optional smooth spatial variation of mu;
- ``label_image`` (a PNG whose colours a legend maps to terrains, stretched over the bounds),
  then ``regions`` (polygons), then ``strips`` (transition strips with wavy edges), painted in
  that order: a later one covers an earlier one;
- ``course``: a shipped course name or a course file (relative to the world file), optional.

Shipped worlds live in ``pcvfe_drake/data/worlds/<name>.yaml``.
"""

import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

WORLD_DIR = Path(__file__).resolve().parents[1] / "data" / "worlds"
"""Folder of the shipped world files."""

MU_RANGE = (0.0, 2.0)
"""A terrain's mu must lie in (0, 2]: above 2 no tyre model of the project is calibrated."""

MAX_CELLS = 200_000_000
"""Largest raster a world may ask for (one byte per cell: 200 MB)."""

_COLOUR_RE = re.compile(r"^#[0-9a-fA-F]{6}$")


@dataclass
class MuVariation:
    """A smooth spatial variation of a terrain's mu: a seeded Gaussian random field of standard
    deviation ``amplitude`` and correlation length ``length_scale_m``, added to the terrain's mu
    (the result kept within (0, 2]). Real ground is not one number; this tests what a per-terrain
    estimate does with that."""

    amplitude: float = 0.0
    """Standard deviation of the variation [-] (0: none)."""
    length_scale_m: float = 10.0
    """Correlation length of the field [m]."""
    seed: int = 0
    """Seed of the field (each terrain draws its own field from it)."""


@dataclass
class TerrainSpec:
    """One terrain of the world."""

    name: str = ""
    """Unique name, used by regions, strips, legends and scenario overrides."""
    texture: str = ""
    """A shipped texture name (``textures/index.yaml``) or an image file (a photo of the ground,
    relative to the world file)."""
    mu: float = 0.0
    """True friction coefficient [-], in (0, 2]."""
    tile_m: float = 0.0
    """World size of one tile of an image-file texture [m] (0: 2 m); shipped textures carry
    their own."""
    variation: MuVariation | None = None
    """Optional smooth spatial variation of mu."""


@dataclass
class RegionSpec:
    """A polygon of one terrain; later regions cover earlier ones."""

    terrain: str = ""
    polygon: list[list[float]] = field(default_factory=list)
    """Vertices ``[[x, y], ...]`` [m], at least three, not crossing itself."""


@dataclass
class Wave:
    """One sine component of a strip edge: ``amplitude_m * sin(2 pi s / wavelength_m + phase_rad)``
    with ``s`` the distance along the strip from its midpoint [m]."""

    amplitude_m: float = 0.0
    wavelength_m: float = 1.0
    phase_rad: float = 0.0


@dataclass
class StripSpec:
    """A transition strip: a straight band of ``width_m`` from ``start`` to ``end`` whose edges
    wave by the sum of their ``Wave`` components (offsets to the left of the direction
    start -> end), sampled every ``sample_m``. A strip's terrain (when it appears nowhere else) is
    a transition: its visits are too short to form a context, so the scores leave it out."""

    terrain: str = ""
    start: list[float] = field(default_factory=list)
    """[x, y] of one end [m]."""
    end: list[float] = field(default_factory=list)
    """[x, y] of the other end [m]."""
    width_m: float = 3.0
    left_waves: list[Wave] = field(default_factory=list)
    right_waves: list[Wave] = field(default_factory=list)
    sample_m: float = 0.25
    """Spacing of the edge samples along the strip [m] (straight between samples)."""


@dataclass
class LabelImageSpec:
    """A label image: a PNG stretched over the world's bounds (row 0 north), each colour a
    terrain by the legend. Painted first; regions and strips cover it."""

    file: str = ""
    """PNG file, relative to the world file."""
    legend: dict[str, str] = field(default_factory=dict)
    """``"#rrggbb"`` colour -> terrain name; every colour of the image must be in it."""


@dataclass
class WorldSpec:
    """One world. See the module docstring and docs/worlds.md."""

    name: str = "world"
    description: str = ""
    bounds_m: list[float] = field(default_factory=list)
    """``[x_min, x_max, y_min, y_max]`` of the raster [m]."""
    resolution_m: float = 0.05
    """Side of one raster cell [m]."""
    terrains: list[TerrainSpec] = field(default_factory=list)
    label_image: LabelImageSpec | None = None
    regions: list[RegionSpec] = field(default_factory=list)
    strips: list[StripSpec] = field(default_factory=list)
    course: str = ""
    """A shipped course name or a course file relative to the world file ("" : none; a scenario
    must then name one)."""

    def terrain_names(self) -> list[str]:
        return [t.name for t in self.terrains]

    def transition_terrains(self) -> tuple[str, ...]:
        """Terrains painted by strips only (left out of the context scores)."""
        painted = {r.terrain for r in self.regions}
        if self.label_image is not None:
            painted |= set(self.label_image.legend.values())
        strips = [s.terrain for s in self.strips]
        return tuple(dict.fromkeys(n for n in strips if n not in painted))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class TerrainOverride:
    """A scenario's change to one of its world's terrains."""

    mu: float | None = None
    """The terrain's true friction in this scenario (None: the world's)."""


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def lowest_mu(world: WorldSpec) -> float:
    """The lowest nominal friction among the world's terrains [-] (a scenario's ``terrains``
    overrides applied first by ``worlds.build.apply_overrides``). A terrain's spatial
    variation is left out: it is the ground's spread around the friction an operator would
    name."""
    return min(float(t.mu) for t in world.terrains)


def mu_problem(value) -> str:
    """Why ``value`` is not a valid mu ("" when it is)."""
    lo, hi = MU_RANGE
    if not _is_number(value) or not lo < value <= hi:
        return f"must be a number in ({lo:g}, {hi:g}]"
    return ""


def point_problem(value) -> str:
    if not (isinstance(value, list) and len(value) == 2 and all(_is_number(v) for v in value)):
        return "must be a point [x, y] of two finite numbers"
    return ""


def polygon_self_intersection(points) -> tuple[int, int] | None:
    """Indices ``(i, j)`` of two non-adjacent edges of the closed polygon that cross, or None.
    Edge ``i`` joins vertex ``i`` to ``i + 1`` (the last joins back to the first)."""
    import numpy as np

    p = np.asarray(points, dtype=float)
    q = np.roll(p, -1, axis=0)
    return _first_crossing(p, q, closed=True)


def _first_crossing(p, q, *, closed: bool) -> tuple[int, int] | None:
    """First pair ``(i, j)``, ``i < j``, of non-adjacent segments ``p[k] -> q[k]`` that cross.
    Two crossing segments have midpoints closer than the longer one's length, so only such
    pairs (a k-d tree's) are tested."""
    import numpy as np
    from scipy.spatial import cKDTree

    n = len(p)
    d = q - p
    longest = float(np.sqrt((d**2).sum(axis=1)).max()) if n else 0.0
    pairs = cKDTree(0.5 * (p + q)).query_pairs(longest * (1 + 1e-9), output_type="ndarray")
    if pairs.size == 0:
        return None
    ii, jj = pairs[:, 0], pairs[:, 1]
    keep = jj >= ii + 2
    if closed:
        keep &= ~((ii == 0) & (jj == n - 1))
    ii, jj = ii[keep], jj[keep]
    r, s_ = d[ii], d[jj]
    denom = r[:, 0] * s_[:, 1] - r[:, 1] * s_[:, 0]
    w = p[jj] - p[ii]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[:, 0] * s_[:, 1] - w[:, 1] * s_[:, 0]) / denom
        u = (w[:, 0] * r[:, 1] - w[:, 1] * r[:, 0]) / denom
    hit = np.flatnonzero((denom != 0) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1))
    if hit.size == 0:
        return None
    k = hit[np.lexsort((jj[hit], ii[hit]))[0]]
    return int(ii[k]), int(jj[k])


def world_problems(world: WorldSpec) -> list[str]:
    """Every problem with the values of ``world``, as ``"field=value: reason"`` strings (file
    references are checked when the world is built, relative to its file)."""
    problems: list[str] = []

    def need(ok: bool, name: str, value, reason: str) -> None:
        if not ok:
            problems.append(f"{name}={value!r}: {reason}")

    need(bool(str(world.name).strip()), "name", world.name, "must not be empty")
    b = world.bounds_m
    bounds_ok = isinstance(b, list) and len(b) == 4 and all(_is_number(v) for v in b)
    need(bounds_ok, "bounds_m", b, "must be [x_min, x_max, y_min, y_max] (numbers)")
    if bounds_ok:
        need(b[1] > b[0] and b[3] > b[2], "bounds_m", b, "needs x_max > x_min and y_max > y_min")
    res = world.resolution_m
    need(_is_number(res) and res > 0, "resolution_m", res, "must be a cell size > 0 m")
    if bounds_ok and _is_number(res) and res > 0 and b[1] > b[0] and b[3] > b[2]:
        cells = round((b[1] - b[0]) / res) * round((b[3] - b[2]) / res)
        need(cells <= MAX_CELLS, "resolution_m", res, f"gives {cells} cells (at most {MAX_CELLS})")
    names = world.terrain_names()
    need(len(names) > 0, "terrains", names, "name at least one terrain")
    need(len(names) < 255, "terrains", len(names), "at most 254 terrains")
    for i, t in enumerate(world.terrains):
        where = f"terrains[{i}]"
        need(bool(str(t.name).strip()), f"{where}.name", t.name, "must not be empty")
        need(names.count(t.name) == 1, f"{where}.name", t.name, "used by two terrains")
        need(bool(str(t.texture).strip()), f"{where}.texture", t.texture, "must name a texture")
        why = mu_problem(t.mu)
        need(not why, f"{where}.mu", t.mu, why)
        need(_is_number(t.tile_m) and t.tile_m >= 0, f"{where}.tile_m", t.tile_m, "must be >= 0")
        if t.variation is not None:
            v = t.variation
            need(
                _is_number(v.amplitude) and 0 <= v.amplitude <= 1,
                f"{where}.variation.amplitude",
                v.amplitude,
                "must be in [0, 1]",
            )
            need(
                _is_number(v.length_scale_m) and v.length_scale_m > 0,
                f"{where}.variation.length_scale_m",
                v.length_scale_m,
                "must be > 0 m",
            )
            need(
                isinstance(v.seed, int) and v.seed >= 0,
                f"{where}.variation.seed",
                v.seed,
                "must be an integer >= 0",
            )
    known = set(names)
    for i, r in enumerate(world.regions):
        where = f"regions[{i}]"
        need(r.terrain in known, f"{where}.terrain", r.terrain, f"is not one of {names}")
        pts = r.polygon
        need(len(pts) >= 3, f"{where}.polygon", pts, "needs at least 3 points")
        bad = [k for k, p in enumerate(pts) if point_problem(p)]
        need(
            not bad,
            f"{where}.polygon[{bad[0] if bad else 0}]",
            pts[bad[0]] if bad else None,
            "must be a point [x, y] of two finite numbers",
        )
        if len(pts) >= 3 and not bad:
            crossing = polygon_self_intersection(pts)
            need(
                crossing is None,
                f"{where}.polygon",
                f"{len(pts)} points",
                f"crosses itself (edges {crossing} meet)",
            )
    for i, s in enumerate(world.strips):
        where = f"strips[{i}]"
        need(s.terrain in known, f"{where}.terrain", s.terrain, f"is not one of {names}")
        for end in ("start", "end"):
            why = point_problem(getattr(s, end))
            need(not why, f"{where}.{end}", getattr(s, end), why)
        if not point_problem(s.start) and not point_problem(s.end):
            need(s.start != s.end, f"{where}.end", s.end, "must differ from start")
        need(_is_number(s.width_m) and s.width_m > 0, f"{where}.width_m", s.width_m, "must be > 0")
        need(_is_number(s.sample_m) and s.sample_m > 0, f"{where}.sample_m", s.sample_m, "> 0")
        for side in ("left_waves", "right_waves"):
            for k, w in enumerate(getattr(s, side)):
                ok = _is_number(w.amplitude_m) and _is_number(w.phase_rad)
                ok &= _is_number(w.wavelength_m) and w.wavelength_m != 0
                need(
                    ok,
                    f"{where}.{side}[{k}]",
                    dataclasses.asdict(w),
                    "needs finite numbers and a non-zero wavelength_m",
                )
    if world.label_image is not None:
        li = world.label_image
        need(bool(li.file.strip()), "label_image.file", li.file, "must name a PNG file")
        need(bool(li.legend), "label_image.legend", li.legend, "must map colours to terrains")
        for colour, terrain in li.legend.items():
            need(
                bool(_COLOUR_RE.match(str(colour))),
                f"label_image.legend.{colour}",
                colour,
                "must be a colour '#rrggbb'",
            )
            need(
                terrain in known, f"label_image.legend.{colour}", terrain, f"is not one of {names}"
            )
    need(
        bool(world.regions) or world.label_image is not None,
        "regions",
        world.regions,
        "give regions or a label_image",
    )
    return problems


def parse_colour(colour: str) -> tuple[int, int, int]:
    """``"#rrggbb"`` -> (r, g, b)."""
    c = colour.lstrip("#")
    return int(c[0:2], 16), int(c[2:4], 16), int(c[4:6], 16)


def shipped_worlds() -> list[str]:
    """Names of the worlds shipped in ``pcvfe_drake/data/worlds``."""
    return sorted(p.stem for p in WORLD_DIR.glob("*.yaml"))


def resolve_world_path(path_or_name: str | Path, relative_to: Path | None = None) -> Path:
    """The YAML file of a world given as a shipped name or a file (a relative file: relative to
    ``relative_to`` when given and it exists there, else to the working directory)."""
    text = str(path_or_name).strip()
    if not text:
        raise FileNotFoundError("no world given: name a shipped world or a world file")
    candidates = []
    candidate = Path(text).expanduser()
    if relative_to is not None and not candidate.is_absolute():
        candidates.append(relative_to / candidate)
    candidates.append(candidate)
    for c in candidates:
        if c.is_file():
            return c.resolve()
    shipped = WORLD_DIR / f"{text}.yaml"
    if "/" not in text and shipped.is_file():
        return shipped
    raise FileNotFoundError(
        f"world {text!r} is neither a file nor a shipped world "
        f"(shipped: {', '.join(shipped_worlds())})"
    )
