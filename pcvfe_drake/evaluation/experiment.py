"""Experiment files of ``pcvfe evaluate``: a grid of scenario x world x friction source x seed
(no pydrake).

An experiment names the scenarios to run, the friction sources to compare (each one a set of
scenario overrides, e.g. ``estimator: ukf`` or ``nmpc.model: ks``), how many seeds, how long each
run lasts and overrides shared by every run. It is a YAML file loaded into :class:`Experiment`
with ``pydrake.common.yaml.yaml_load_typed`` by ``pcvfe_drake.diagrams.experiment_io`` (the core
never imports pydrake). Like the scenario module, this one does not use
``from __future__ import annotations``: ``yaml_load_typed`` needs real types in the fields.

Overrides are a flat mapping from a dotted scenario field to a value
(``{nmpc.model: ks, fitter.buffer_s: 20}``); they are applied to the scenario's YAML mapping and
the result is loaded and validated as a scenario, so a bad override gets the scenario loader's
error naming the field. Every run of the grid is a :class:`RunSpec`: the complete scenario it
runs (as a mapping, seed and run length included), so a worker needs nothing but the spec.

Worlds: ``worlds`` lists world files or shipped worlds and/or asks for generated ones
(``worlds: {generate: {count: 20, seed: 100, mu_range: [0.15, 1.0]}}``); every scenario then
runs in every world (its own world and course replaced), so that one number is not the number
of the one world it was tuned on. Without ``worlds`` each scenario runs in its own world.

Shipped experiments live in ``pcvfe_drake/data/experiments/<name>.yaml``.
"""

import copy
import dataclasses
import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

EXPERIMENT_DIR = Path(__file__).resolve().parents[1] / "data" / "experiments"
"""Folder of the shipped experiment files."""

OverrideValue = bool | int | float | str
"""Value of one scenario override (a YAML scalar)."""


@dataclass
class Source:
    """One friction source (method) of the comparison: a name and the overrides that select it."""

    name: str = ""
    """Short name used in tables and plots (letters, digits, ``_`` and ``-``)."""
    description: str = ""
    overrides: dict[str, OverrideValue] = field(default_factory=dict)
    """Dotted scenario field -> value, applied after the experiment's own overrides."""


@dataclass
class Variant:
    """One variant of every scenario (a car, a friction mapping, ...): a name and the overrides
    that make it. Each scenario runs once per variant, as the scenario ``<name>-<variant>``."""

    name: str = ""
    """Short name appended to the scenario's (letters, digits, ``_`` and ``-``)."""
    overrides: dict[str, OverrideValue] = field(default_factory=dict)
    """Dotted scenario field -> value, applied after the experiment's own overrides."""
    floor_offset: float | None = None
    """The operator's stated lowest friction in this variant's runs: each run's world's lowest
    terrain friction plus this [-] (replaces ``worlds.floor_offset``; None: that one)."""


@dataclass
class QuickSettings:
    """What ``--quick`` changes: fewer seeds and shorter runs, for a first look."""

    seeds: int = 2
    duration_s: float = 30.0
    """Simulated time of each quick run [s] (replaces laps / duration_s of the experiment)."""


@dataclass
class GenerateWorlds:
    """Generated worlds of an experiment (``pcvfe world generate``, docs/worlds.md)."""

    count: int = 0
    """How many: seeds ``seed`` .. ``seed + count - 1``."""
    seed: int = 0
    mu_range: list[float] = field(default_factory=lambda: [0.15, 1.0])
    """Range of the drawn frictions [LO, HI]."""
    terrains: int | None = None
    """Terrain regions per world (None: drawn, 3-6)."""
    vehicle: str = ""
    """Vehicle the courses must be drivable by and scaled to ("": the first scenario's)."""


@dataclass
class WorldSettings:
    """The worlds an experiment runs every scenario in (none: each scenario's own world)."""

    names: list[str] = field(default_factory=list)
    """Shipped world names or world files (relative paths: relative to the experiment file)."""
    generate: GenerateWorlds | None = None
    floor_offset: float | None = None
    """The operator's stated lowest friction in each run: the lowest terrain friction of the
    run's world plus this [-], given to ``fitter.handing.floor_mu`` and ``fixed.conservative_mu``
    (an explicit override of either still wins). A scenario's stated floor describes its own
    world; on worlds drawn over a friction range it would be a different guess in each. None:
    the scenario's own values."""


@dataclass
class Experiment:
    """A comparison grid. Every field has a default except what makes a grid: sources."""

    name: str = "experiment"
    description: str = ""
    scenarios: list[str] = field(default_factory=lambda: ["paper_sim"])
    """Shipped scenario names or YAML files (relative paths: relative to the experiment file)."""
    sources: list[Source] = field(default_factory=list)
    variants: list[Variant] = field(default_factory=list)
    """Variants of every scenario (empty: each scenario as it is)."""
    reference: str = ""
    """The source every other one is compared with, seed by seed (default: the first source)."""
    seeds: int = 10
    """Number of seeds per scenario and source: ``first_seed`` .. ``first_seed + seeds - 1``."""
    first_seed: int = 0
    laps: float | None = None
    """Laps per run (None: the scenario's own run length unless ``duration_s`` is given)."""
    duration_s: float | None = None
    """Simulated time per run [s]; takes precedence over ``laps``."""
    overrides: dict[str, OverrideValue] = field(default_factory=dict)
    """Overrides applied to every run (before the source's own)."""
    plot_seed: int | None = None
    """The seed whose mu_hat over time the report plots for every source (None: first_seed)."""
    quick: QuickSettings = field(default_factory=QuickSettings)
    worlds: WorldSettings = field(default_factory=WorldSettings)

    @property
    def reference_source(self) -> str:
        return self.reference or (self.sources[0].name if self.sources else "")

    def seed_list(self, seeds: int | None = None) -> list[int]:
        n = self.seeds if seeds is None else int(seeds)
        return list(range(self.first_seed, self.first_seed + n))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def with_sources(self, names: list[str]) -> "Experiment":
        """A copy that runs only the sources ``names`` (in the experiment's order), so one part
        of a grid can be run or rerun; the reference stays when kept, else the first kept
        source is it. Raises ValueError naming any unknown source."""
        known = [s.name for s in self.sources]
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ValueError(
                f"--sources: unknown source(s) {', '.join(unknown)} of experiment {self.name} "
                f"(its sources: {', '.join(known)})"
            )
        kept = [s for s in self.sources if s.name in names]
        reference = self.reference if self.reference in names else ""
        return dataclasses.replace(self, sources=kept, reference=reference)


_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$")


def _number(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _positive(x) -> bool:
    return _number(x) and x > 0


def experiment_problems(exp: Experiment) -> list[str]:
    """Every problem with the values of ``exp`` as ``"field=value: reason"`` strings."""
    problems: list[str] = []

    def need(ok: bool, name: str, value, reason: str) -> None:
        if not ok:
            problems.append(f"{name}={value!r}: {reason}")

    need(bool(_NAME_RE.match(exp.name)), "name", exp.name, "letters, digits, '_' or '-' only")
    need(len(exp.scenarios) > 0, "scenarios", exp.scenarios, "name at least one scenario")
    for i, s in enumerate(exp.scenarios):
        need(bool(str(s).strip()), f"scenarios[{i}]", s, "must not be empty")
    need(len(exp.sources) > 0, "sources", exp.sources, "name at least one friction source")
    names = [s.name for s in exp.sources]
    for key, items in (("sources", exp.sources), ("variants", exp.variants)):
        listed = [item.name for item in items]
        for i, name in enumerate(listed):
            where = f"{key}[{i}].name"
            need(bool(_NAME_RE.match(name)), where, name, "letters, digits, '_' or '-' only")
            need(listed.count(name) == 1, where, name, f"used by two {key}")
    if exp.reference:
        need(exp.reference in names, "reference", exp.reference, f"must be one of {names}")
    need(
        isinstance(exp.seeds, int) and exp.seeds >= 1, "seeds", exp.seeds, "must be an integer >= 1"
    )
    need(
        isinstance(exp.first_seed, int) and exp.first_seed >= 0,
        "first_seed",
        exp.first_seed,
        "must be an integer >= 0",
    )
    if exp.laps is not None:
        need(_positive(exp.laps), "laps", exp.laps, "must be > 0")
    if exp.duration_s is not None:
        need(_positive(exp.duration_s), "duration_s", exp.duration_s, "must be > 0")
    need(
        isinstance(exp.quick.seeds, int) and exp.quick.seeds >= 1,
        "quick.seeds",
        exp.quick.seeds,
        "must be an integer >= 1",
    )
    need(_positive(exp.quick.duration_s), "quick.duration_s", exp.quick.duration_s, "must be > 0")
    for i, w in enumerate(exp.worlds.names):
        need(bool(str(w).strip()), f"worlds.names[{i}]", w, "must not be empty")
    offsets = [("worlds.floor_offset", exp.worlds.floor_offset)] + [
        (f"variants[{i}].floor_offset", v.floor_offset) for i, v in enumerate(exp.variants)
    ]
    for name, offset in offsets:
        if offset is not None:
            need(
                _number(offset) and -1.0 <= offset <= 1.0,
                name,
                offset,
                "must be a number in [-1, 1] (added to the world's lowest friction) or null",
            )
    gen = exp.worlds.generate
    if gen is not None:
        need(
            isinstance(gen.count, int) and gen.count >= 1,
            "worlds.generate.count",
            gen.count,
            "must be an integer >= 1",
        )
        need(
            isinstance(gen.seed, int) and gen.seed >= 0,
            "worlds.generate.seed",
            gen.seed,
            "must be an integer >= 0",
        )
        mr = gen.mu_range
        need(
            len(mr) == 2 and all(_positive(v) for v in mr) and mr[0] <= mr[1] <= 2.0,
            "worlds.generate.mu_range",
            mr,
            "must be [LO, HI] with 0 < LO <= HI <= 2",
        )
        if gen.terrains is not None:
            need(
                isinstance(gen.terrains, int) and 3 <= gen.terrains <= 6,
                "worlds.generate.terrains",
                gen.terrains,
                "must be an integer in [3, 6]",
            )
    if exp.plot_seed is not None:
        need(
            isinstance(exp.plot_seed, int) and exp.plot_seed >= 0,
            "plot_seed",
            exp.plot_seed,
            "must be an integer >= 0",
        )
    return problems


def apply_overrides(scenario: dict, overrides: dict[str, Any], source: str) -> dict:
    """A copy of the scenario mapping ``scenario`` with the dotted ``overrides`` set.

    A path whose parent is not a mapping of the scenario raises ValueError naming ``source``
    and the field (unknown leaf names are left to the scenario loader, which lists the known).
    """
    out = copy.deepcopy(scenario)
    for dotted, value in overrides.items():
        parts = str(dotted).split(".")
        node = out
        for depth, part in enumerate(parts[:-1]):
            child = node.get(part) if isinstance(node, dict) else None
            if not isinstance(child, dict):
                where = ".".join(parts[: depth + 1])
                groups = ", ".join(k for k, v in out.items() if isinstance(v, dict))
                raise ValueError(
                    f"{source}: override {dotted!r}: {where!r} is not a group of scenario "
                    f"fields (groups: {groups})"
                )
            node = child
        node[parts[-1]] = value
    return out


FILE_FIELDS = ("world", "course")
"""Scenario fields that may name a file (a world or course YAML): the run depends on the
file's content, not on where it lies."""


_NAMED_COURSE: dict[str, str] = {}
"""The course file a world file names (``""``: none), by the sha256 of the world file's bytes:
every run of a grid over worlds hashes its world, and parsing a world's YAML costs far more than
reading it."""


def _named_course(data: bytes, key: str) -> str:
    """The ``course`` a world file's ``data`` (sha256 ``key``) names, ``""`` where none."""
    if key not in _NAMED_COURSE:
        try:
            named = yaml.safe_load(data)
        except yaml.YAMLError:
            named = None  # not YAML that parses: its bytes alone
        course = named.get("course") if isinstance(named, dict) else None
        _NAMED_COURSE[key] = course if isinstance(course, str) else ""
    return _NAMED_COURSE[key]


def _file_digest(path: Path) -> str:
    """``sha256:`` of a world or course file's bytes, with those of the course file a world
    names beside it (a generated world's ``course: NAME_course.yaml``)."""
    data = path.read_bytes()
    digest = hashlib.sha256(data)
    course = _named_course(data, digest.hexdigest())
    if course and (path.parent / course).is_file():
        digest.update((path.parent / course).read_bytes())
    return "sha256:" + digest.hexdigest()


def spec_hash(scenario: dict) -> str:
    """Short hash of a complete scenario mapping: a run is the same run iff this is equal. A
    world or course given as a file path counts by its content (:func:`_file_digest`), so a
    results folder whose generated worlds moved with it (copied, renamed, on another machine)
    still resumes: its runs are the same runs."""
    keyed = dict(scenario)
    for name in FILE_FIELDS:
        value = keyed.get(name)
        if isinstance(value, str) and value.endswith((".yaml", ".yml")) and Path(value).is_file():
            keyed[name] = _file_digest(Path(value))
    text = json.dumps(keyed, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


@dataclass(frozen=True)
class RunSpec:
    """One run of a grid: everything a worker needs (the scenario as a complete mapping)."""

    run_id: str
    experiment: str
    scenario_name: str
    source: str
    seed: int
    scenario: dict = field(hash=False, compare=False)
    spec_hash: str = ""
    world: str = ""
    """The world's name when the experiment has a world axis ("" : the scenario's own)."""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def run_id(scenario_name: str, source: str, seed: int) -> str:
    """The folder name of a run: ``<scenario>__<source>__s<seed>``."""
    safe = re.sub(r"[^A-Za-z0-9_-]+", "-", scenario_name)
    return f"{safe}__{source}__s{seed:03d}"


def shipped_experiments() -> list[str]:
    """Names of the experiments shipped in ``pcvfe_drake/data/experiments``."""
    return sorted(p.stem for p in EXPERIMENT_DIR.glob("*.yaml"))


def resolve_experiment_path(path_or_name: str | Path) -> Path:
    """The YAML file of an experiment given as a path or a shipped experiment name."""
    candidate = Path(path_or_name).expanduser()
    if candidate.is_file():
        return candidate.resolve()
    shipped = EXPERIMENT_DIR / f"{path_or_name}.yaml"
    if shipped.is_file():
        return shipped
    raise FileNotFoundError(
        f"experiment {str(path_or_name)!r} is neither a file nor a shipped experiment "
        f"(shipped: {', '.join(shipped_experiments()) or 'none'})"
    )
