"""Loading scenario YAML files into ``pcvfe_drake.runs.scenario.Scenario`` with ``yaml_load_typed``.

The dataclasses live in the core (``pcvfe_drake/runs/scenario.py``, no pydrake); the loader lives
here
because it uses ``pydrake.common.yaml``. Before handing the text to ``yaml_load_typed`` the loader
walks the YAML against the dataclass schema so that a malformed file gets an error naming the file
and the dotted field (``clustering.min_cluster_size_s``), not only the leaf name.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_load_typed

from pcvfe_drake.runs.scenario import Scenario, resolve_scenario_path
from pcvfe_drake.vehicle.params import PRESETS


def _schema_problems(schema, data, prefix: str) -> list[str]:
    """Problems of YAML ``data`` against dataclass ``schema`` (unknown fields, wrong types)."""
    if not isinstance(data, dict):
        where = f"field {prefix.rstrip('.')!r}" if prefix else "the document"
        return [f"{where} must be a mapping of fields, got {type(data).__name__} {data!r}"]
    hints = typing.get_type_hints(schema)
    fields = {f.name: hints[f.name] for f in dataclasses.fields(schema)}
    problems = []
    for key, value in data.items():
        name = f"{prefix}{key}"
        if key not in fields:
            problems.append(f"unknown field {name!r} (known: {', '.join(sorted(fields))})")
            continue
        problems.extend(_value_problems(fields[key], value, name))
    return problems


def _value_problems(hint, value, name: str) -> list[str]:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return []
        (inner,) = [a for a in args if a is not type(None)]
        return _value_problems(inner, value, name)
    if dataclasses.is_dataclass(hint):
        return _schema_problems(hint, value, f"{name}.")
    expected = {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}
    if hint is bool:
        ok = isinstance(value, bool)
    elif hint is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    elif hint is str:
        ok = isinstance(value, str)
    else:
        return []  # containers: left to yaml_load_typed
    if not ok:
        return [f"field {name!r} must be {expected[hint]}, got {value!r}"]
    return []


def scenario_from_yaml_text(text: str, source: str = "<string>") -> Scenario:
    """Parse scenario YAML ``text``; errors name ``source`` and the offending field."""
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{source}: not valid YAML: {exc}") from exc
    if raw is None:
        raw = {}
    problems = _schema_problems(Scenario, raw, "")
    if problems:
        raise ValueError(f"{source}: malformed scenario: " + "; ".join(problems))
    try:
        scenario = yaml_load_typed(schema=Scenario, data=text)
    except (RuntimeError, ValueError, TypeError) as exc:
        raise ValueError(f"{source}: malformed scenario: {exc}") from exc
    return scenario.validate(source)


def load_scenario(path_or_name: str | Path | None = None) -> Scenario:
    """Load a scenario from a YAML file or a shipped scenario name (None: the default).

    A ``vehicle`` that is not a preset name is a vehicle YAML file; a relative path is taken
    relative to the scenario file and stored as an absolute path.
    """
    path = resolve_scenario_path(path_or_name)
    scenario = scenario_from_yaml_text(path.read_text(), source=str(path))
    if scenario.vehicle not in PRESETS:
        vehicle_path = Path(scenario.vehicle).expanduser()
        if not vehicle_path.is_absolute():
            vehicle_path = path.parent / vehicle_path
        if not vehicle_path.is_file():
            raise FileNotFoundError(
                f"{path}: field 'vehicle'={scenario.vehicle!r} is neither a preset "
                f"({', '.join(sorted(PRESETS))}) nor a file ({vehicle_path})"
            )
        scenario = dataclasses.replace(scenario, vehicle=str(vehicle_path.resolve()))
    return scenario


def save_scenario(scenario: Scenario, path: str | Path) -> Path:
    """Write ``scenario`` as YAML (every field) to ``path``; returns the path."""
    path = Path(path)
    path.write_text(yaml.safe_dump(scenario.to_dict(), sort_keys=False))
    return path
