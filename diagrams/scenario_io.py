"""Loading scenario YAML files into ``pcvfe_drake.runs.scenario.Scenario`` with ``yaml_load_typed``.

The dataclasses live in the core (``pcvfe_drake/runs/scenario.py``, no pydrake); the loader lives
here because it uses ``pydrake.common.yaml``.

Layers: :func:`load_scenario` reads each file with ``yaml_load_typed(..., defaults=previous)``,
so the first file (a shipped scenario, say) lands on top of the dataclass defaults and every
further file (a user's overrides) on top of that; a file names only what it changes.

Before handing a file to ``yaml_load_typed`` the loader walks its YAML against the dataclass
schema so that a malformed file gets an error naming the file and the dotted field
(``clustering.min_cluster_size``), not only the leaf name. Numbers are read as YAML 1.2 reads
them: ``2e-3``, ``1e1`` and ``1.0e12`` are numbers (PyYAML's YAML 1.1 reads them as strings),
and an integer field takes ``1e1`` as 10. An empty file means "all defaults".
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import GetIntegrationSchemes

from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.handing.config import FLAT_FIELDS
from pcvfe_drake.runs.scenario import (
    DERIVED_FIELDS,
    REPLACED_FIELDS,
    Scenario,
    resolve_scenario_path,
)
from pcvfe_drake.runs.scenario_files import resolve_file_field
from pcvfe_drake.vehicle.params import PRESETS, load_vehicle
from pcvfe_drake.worlds.build import apply_overrides
from pcvfe_drake.worlds.world_file import WorldSpec, resolve_world_path, world_problems
from pcvfe_drake.yaml_unique import UniqueKeyLoader

_YAML12_FLOAT = re.compile(r"^[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?$")
"""A number in YAML 1.2's core schema (PyYAML's YAML 1.1 needs a dot before an exponent)."""


class _TaggedLoader(UniqueKeyLoader):
    """YAML's safe loader (libyaml's where available: large world files load fast; a key given
    twice in one mapping refused, ``pcvfe_drake.yaml_unique``) that reads a
    tagged mapping (``!Probe {hold_s: 3}``, Drake's variant syntax) as the mapping plus a
    ``"_tag": "!Probe"`` key, the form ``yaml_load_data(private=True)`` gives and the schema
    check reads, so one reader serves every file."""


def _tagged(loader: yaml.SafeLoader, suffix: str, node: yaml.Node) -> dict:
    if isinstance(node, yaml.MappingNode):
        body = loader.construct_mapping(node, deep=True)
    elif isinstance(node, yaml.ScalarNode) and node.value == "":
        body = {}
    else:
        raise yaml.constructor.ConstructorError(
            None, None, f"the tag !{suffix} must tag a mapping (!{suffix} {{...}})", node.start_mark
        )
    return {"_tag": f"!{suffix}", **body}


_TaggedLoader.add_multi_constructor("!", _tagged)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
"""libyaml's safe dumper where PyYAML has it (a world file holds long lists of vertices)."""


def _number(value):
    """``value`` as a float when it is a YAML 1.2 number written as text, else None."""
    if isinstance(value, str) and _YAML12_FLOAT.match(value.strip()):
        return float(value)
    return None


def schema_problems(schema, data) -> tuple[dict, list[str]]:
    """YAML ``data`` checked against dataclass ``schema``: the data with numbers typed, and every
    problem naming the dotted field (``sources[1].overrides.nmpc.model``). Also used for
    experiment files."""
    problems: list[str] = []
    return _normalise(schema, data, "", problems), problems


def _normalise(schema, data, prefix: str, problems: list[str]):
    """``data`` checked against dataclass ``schema`` (problems appended) with numbers typed."""
    if not isinstance(data, dict):
        where = f"field {prefix.rstrip('.')!r}" if prefix else "the document"
        problems.append(f"{where} must be a mapping of fields, got {type(data).__name__} {data!r}")
        return data
    hints = typing.get_type_hints(schema)
    fields = {f.name: hints[f.name] for f in dataclasses.fields(schema)}
    out = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if schema is Scenario and key in REPLACED_FIELDS:
            problems.append(f"field {name!r} was {REPLACED_FIELDS[key]}")
            continue
        if key not in fields:
            moved = FLAT_FIELDS.get(key) if schema is LiveFitConfig else None
            if moved is not None:
                problems.append(f"field {name!r} is now {moved}")
                continue
            problems.append(f"unknown field {name!r} (known: {', '.join(sorted(fields))})")
            continue
        if name in DERIVED_FIELDS:
            problems.append(f"field {name!r} is set from {DERIVED_FIELDS[name]}; set that instead")
            continue
        out[key] = _normalise_value(fields[key], value, name, problems)
    return out


def _normalise_value(hint, value, name: str, problems: list[str]):
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if all(dataclasses.is_dataclass(a) for a in inner) and isinstance(value, dict):
            return _normalise_variant(inner, value, name, problems)
        if len(inner) > 1:  # a union of scalars (an experiment's override value)
            if not isinstance(value, tuple(inner)):
                names = " or ".join(a.__name__ for a in inner)
                problems.append(f"field {name!r} must be {names}, got {value!r}")
            return value
        return _normalise_value(inner[0], value, name, problems)
    if dataclasses.is_dataclass(hint):
        return _normalise(hint, value, f"{name}.", problems)
    if origin is list:
        if not isinstance(value, list):
            problems.append(f"field {name!r} must be a list, got {value!r}")
            return value
        (item,) = typing.get_args(hint)
        return [_normalise_value(item, v, f"{name}[{i}]", problems) for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            problems.append(f"field {name!r} must be a mapping, got {value!r}")
            return value
        _, item = typing.get_args(hint)
        return {k: _normalise_value(item, v, f"{name}.{k}", problems) for k, v in value.items()}
    expected = {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}
    if hint in (int, float) and _number(value) is not None:
        value = _number(value)
    if hint is int and isinstance(value, float) and value.is_integer():
        value = int(value)
    if hint is bool:
        ok = isinstance(value, bool)
    elif hint is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif hint is str:
        ok = isinstance(value, str)
    else:
        return value  # other containers: left to yaml_load_typed
    if not ok:
        problems.append(f"field {name!r} must be {expected[hint]}, got {value!r}")
    return value


def _normalise_variant(variants, value: dict, name: str, problems: list[str]):
    """A mapping for a union of dataclasses (Drake's tagged variants: ``!Probe {...}`` in a
    file, ``_tag: "!Probe"`` in plain data; no tag: the first alternative)."""
    tag = value.get("_tag")
    body = {k: v for k, v in value.items() if k != "_tag"}
    names = {v.__name__: v for v in variants}
    if tag is None:
        return _normalise(variants[0], body, f"{name}.", problems)
    chosen = names.get(str(tag).lstrip("!"))
    if chosen is None:
        known = ", ".join(f"!{n}" for n in names)
        problems.append(f"field {name!r}: unknown variant {tag} (known: {known})")
        return value
    return {"_tag": f"!{chosen.__name__}", **_normalise(chosen, body, f"{name}.", problems)}


def load_typed_yaml(schema, text: str, source: str, kind: str, defaults=None):
    """YAML ``text`` into dataclass ``schema`` with ``yaml_load_typed`` (on top of ``defaults``
    when given); every error is a ``ValueError`` naming ``source`` and the dotted field. An empty
    text gives ``defaults`` (or the dataclass defaults). ``kind`` names the file in messages."""
    try:
        raw = yaml.load(text, Loader=_TaggedLoader)
    except yaml.YAMLError as exc:
        raise ValueError(f"{source}: not valid YAML: {exc}") from exc
    if raw is None:
        raw = {}
    data, problems = schema_problems(schema, raw)
    if problems:
        raise ValueError(f"{source}: malformed {kind}: " + "; ".join(problems))
    kwargs = {} if defaults is None else {"defaults": defaults}
    try:
        return yaml_load_typed(schema=schema, data=yaml.dump(data, Dumper=_DUMPER), **kwargs)
    except (RuntimeError, ValueError, TypeError, NotImplementedError) as exc:
        raise ValueError(f"{source}: malformed {kind}: {exc}") from exc


def scenario_from_yaml_text(
    text: str, source: str = "<string>", *, defaults: Scenario | None = None
) -> Scenario:
    """Parse scenario YAML ``text`` on top of ``defaults`` (None: the dataclass defaults);
    errors name ``source`` and the offending field. An empty text gives ``defaults``."""
    scenario = load_typed_yaml(
        Scenario, text, source, "scenario", defaults if defaults is not None else Scenario()
    )
    return scenario.validate(source)


def read_yaml_file(path: Path, kind: str = "scenario") -> str:
    """The text of a YAML file; a binary or unreadable file is a ``ValueError`` naming it."""
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{path}: not {'an' if kind[0] in 'aeiou' else 'a'} {kind} file "
            f"(not UTF-8 text: {exc.reason} at byte {exc.start}); "
            "give a YAML file"
        ) from exc
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the {kind} file: {exc.strerror or exc}") from exc


def load_scenario(path_or_name: str | Path | None = None, *overrides: str | Path) -> Scenario:
    """Load a scenario from a YAML file or a shipped scenario name (None: the default), then
    each of ``overrides`` (files or shipped names) on top of it, in order.

    A ``vehicle`` that is not a preset, a ``course`` that is not a shipped course and a
    ``world`` that is not a shipped name are files: a relative path is taken relative to the
    scenario file that names it (``resolve_file_field``) and stored as an absolute path.
    """
    scenario = None
    origin: dict[str, Path] = {}
    for layer in (path_or_name, *overrides):
        path = resolve_scenario_path(layer)
        before = scenario
        text = read_yaml_file(path)
        defaults = scenario if scenario is not None else Scenario()
        scenario = load_typed_yaml(Scenario, text, str(path), "scenario", defaults)
        scenario = _resolve_files(scenario, before, path)  # before the values are checked
        changed = before is None or scenario.vehicle != before.vehicle
        if changed and scenario.vehicle.strip():  # an empty one: named by validate
            load_vehicle(scenario.vehicle)  # its own values first, then what the fitter needs
        scenario.validate(str(path))
        for f in dataclasses.fields(Scenario):
            if before is None or getattr(before, f.name) != getattr(scenario, f.name):
                origin[f.name] = path
    check_scenario_resources(scenario, {k: str(v) for k, v in origin.items()})
    return scenario


def load_checked_yaml(schema, text: str, source: str, kind: str, problems_of):
    """YAML ``text`` into dataclass ``schema`` (:func:`load_typed_yaml`), then checked by
    ``problems_of`` (the object's problems, a list of strings): every problem in one
    ``ValueError`` naming ``source``."""
    value = load_typed_yaml(schema, text, source, kind)
    problems = problems_of(value)
    if problems:
        raise ValueError(f"{source}: invalid {kind}: " + "; ".join(problems))
    return value


def world_from_yaml_text(text: str, source: str = "<string>") -> WorldSpec:
    """Parse and check world YAML ``text``; errors are one line naming ``source`` and the field."""
    return load_checked_yaml(WorldSpec, text, source, "world", world_problems)


def check_scenario_resources(scenario: Scenario, origin: dict[str, str] | None = None) -> None:
    """Check what a scenario names beyond its own values, before any run starts: its vehicle
    file, its world (a file or a shipped name) and the terrains it changes there, its
    integration scheme, its CLIP folder, and an initial speed and a speed cap within the
    vehicle's top speed.
    A problem is a ``ValueError`` naming the file that set the field (``origin``: field name to
    file; default ``"scenario"``) and the field, so that a user learns it from one line, not from
    a run that stops at its first step."""
    origin = origin or {}

    def where(field: str) -> str:
        return origin.get(field, f"scenario {scenario.name!r}")

    vehicle = load_vehicle(scenario.vehicle)  # a file's fields are checked here
    if scenario.initial_speed_mps > vehicle.v_max:
        raise ValueError(
            f"{where('initial_speed_mps')}: initial_speed_mps={scenario.initial_speed_mps!r} is "
            f"above the top speed of the vehicle {vehicle.name!r} (v_max={vehicle.v_max:g} m/s)"
        )
    cap = scenario.nmpc.max_speed_mps
    if cap is not None and cap > vehicle.v_max:
        raise ValueError(
            f"{where('nmpc')}: nmpc.max_speed_mps={cap!r} is above the top speed of the vehicle "
            f"{vehicle.name!r} (v_max={vehicle.v_max:g} m/s)"
        )
    try:
        world_path = resolve_world_path(scenario.world)
    except FileNotFoundError as exc:
        raise ValueError(f"{where('world')}: world: {exc}") from exc
    world = world_from_yaml_text(read_yaml_file(world_path, "world"), str(world_path))
    apply_overrides(world, scenario.terrains, source=where("terrains"))
    schemes = GetIntegrationSchemes()
    if scenario.simulator.integration_scheme not in schemes:
        raise ValueError(
            f"{where('simulator')}: simulator.integration_scheme="
            f"{scenario.simulator.integration_scheme!r} is not one of {schemes}"
        )
    if scenario.uses_clip and not Path(scenario.features.backend).is_dir():
        raise ValueError(
            f"{where('features')}: features.backend={scenario.features.backend!r}: not a CLIP "
            "model folder (a folder holding clip.json; or 'descriptor'; docs/perception.md)"
        )


def _is_shipped_name(field: str, value: str) -> bool:
    """Whether ``value`` of ``field`` names something shipped (not a file)."""
    if field == "vehicle":
        return value in PRESETS
    if field == "course":
        from pcvfe_drake.control.course import course_names

        return value in course_names()
    # Other path fields (a world): a name has no folder and no file suffix.
    return not (Path(value).suffix or "/" in value or "\\" in value)


PATH_FIELDS = ("vehicle", "course", "world")
"""Scenario fields that name a file when they do not name something shipped (and
``fitter.model.file``, always a file)."""


def _resolve_files(scenario: Scenario, before: Scenario | None, path: Path) -> Scenario:
    """``scenario`` with the path fields that the layer ``path`` set resolved against it."""
    changes = {}
    for field in PATH_FIELDS:
        value = getattr(scenario, field, None)
        if not isinstance(value, str) or not value.strip():
            continue
        if before is not None and getattr(before, field, None) == value:
            continue  # set by an earlier layer (already resolved there)
        if not _is_shipped_name(field, value):
            changes[field] = resolve_file_field(value, path, field)
    model = scenario.fitter.model
    earlier = None if before is None else before.fitter.model.file
    if isinstance(model.file, str) and model.file.strip() and model.file != earlier:
        file = resolve_file_field(model.file, path, "fitter.model.file")
        model = dataclasses.replace(model, file=file)
        changes["fitter"] = dataclasses.replace(scenario.fitter, model=model)
    return dataclasses.replace(scenario, **changes) if changes else scenario


def save_scenario(scenario: Scenario, path: str | Path) -> Path:
    """Write ``scenario`` as YAML (every field but the derived ones) to ``path``; returns it."""
    path = Path(path)
    path.write_text(scenario.to_yaml())
    return path
