"""Loading experiment YAML files (``pcvfe evaluate``) and expanding them into run specs.

The dataclasses live in the core (``pcvfe_drake.evaluation.experiment``); the loader lives here
because it uses ``pydrake.common.yaml.yaml_load_typed``. Errors name the file and the dotted
field. :func:`run_specs` loads each scenario of the experiment, applies the experiment's and the
source's overrides, the seed and the run length, and validates the result with the scenario
loader, so every run of the grid is checked before anything is submitted. An experiment's
``worlds`` (listed or generated) make a world axis: every scenario runs in every world.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import yaml

from pcvfe_drake.diagrams.scenario_io import (
    load_checked_yaml,
    load_scenario,
    read_yaml_file,
    scenario_from_yaml_text,
)
from pcvfe_drake.diagrams.world_io import load_world
from pcvfe_drake.evaluation.experiment import (
    Experiment,
    RunSpec,
    Variant,
    apply_overrides,
    experiment_problems,
    resolve_experiment_path,
    run_id,
    spec_hash,
)
from pcvfe_drake.runs.scenario import resolve_scenario_path
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.worlds import build as world_build
from pcvfe_drake.worlds.generate import write_generated_world
from pcvfe_drake.worlds.world_file import (
    WORLD_DIR,
    TerrainOverride,
    lowest_mu,
    resolve_world_path,
)


def experiment_from_yaml_text(text: str, source: str = "<string>") -> Experiment:
    """Parse experiment YAML ``text``; errors name ``source`` and the offending field."""
    return load_checked_yaml(Experiment, text, source, "experiment", experiment_problems)


def load_experiment(path_or_name: str | Path) -> tuple[Experiment, Path]:
    """Load an experiment file or shipped experiment name; returns it and its path."""
    path = resolve_experiment_path(path_or_name)
    return experiment_from_yaml_text(read_yaml_file(path, "experiment"), source=str(path)), path


def _scenario_path(entry: str, experiment_path: Path) -> Path:
    candidate = Path(entry).expanduser()
    if not candidate.is_absolute() and (experiment_path.parent / candidate).is_file():
        return (experiment_path.parent / candidate).resolve()
    return resolve_scenario_path(entry)


MIN_STATED_FLOOR = 0.05
"""The lowest stated floor an offset below a world's lowest friction gives [-] (the handing's
smallest handed friction)."""


def stated_floor(scenario: dict, offset: float, where: str) -> dict:
    """``scenario`` (a dict) with the operator's stated lowest friction set from its world: the
    world's lowest terrain friction plus ``offset``, at least ``MIN_STATED_FLOOR``, as
    ``fitter.handing.floor_mu`` and ``fixed.conservative_mu``."""
    try:
        spec, _ = load_world(scenario["world"])
        changes = {n: TerrainOverride(**c) for n, c in (scenario.get("terrains") or {}).items()}
        spec = world_build.apply_overrides(spec, changes, where)
    except (ValueError, FileNotFoundError) as exc:
        raise ValueError(f"{where}: floor_offset: {exc}") from exc
    floor = max(MIN_STATED_FLOOR, lowest_mu(spec) + offset)
    values = {"fitter.handing.floor_mu": round(floor, 6), "fixed.conservative_mu": round(floor, 6)}
    return apply_overrides(scenario, values, f"{where}: floor_offset")


def experiment_worlds(
    exp: Experiment, experiment_path: Path, worlds_dir: Path | None, progress: bool = False
) -> list[tuple[str, str]]:
    """The worlds of the experiment's world axis as ``(label, world)`` (a shipped name or an
    absolute file); generated worlds are written into ``worlds_dir``. Empty: no world axis."""
    out: list[tuple[str, str]] = []
    for i, entry in enumerate(exp.worlds.names):
        try:
            path = resolve_world_path(entry, experiment_path.parent)
        except FileNotFoundError as exc:
            raise ValueError(f"{experiment_path}: worlds.names[{i}]: {exc}") from exc
        shipped = path.parent == WORLD_DIR and path.stem == entry
        out.append((path.stem, entry if shipped else str(path)))
    gen = exp.worlds.generate
    if gen is not None:
        if worlds_dir is None:
            raise ValueError(f"{experiment_path}: worlds.generate needs a folder for the worlds")
        vehicle_name = gen.vehicle
        if not vehicle_name:
            first = load_scenario(_scenario_path(exp.scenarios[0], experiment_path))
            vehicle_name = first.vehicle
        vehicle = load_vehicle(vehicle_name)
        for seed in range(gen.seed, gen.seed + gen.count):
            if progress:
                print(f"  generating world seed {seed} into {worlds_dir}", flush=True)
            path, _ = write_generated_world(
                seed,
                vehicle,
                worlds_dir,
                terrains=gen.terrains,
                mu_range=(gen.mu_range[0], gen.mu_range[1]),
            )
            out.append((path.stem, str(path.resolve())))
    labels = [label for label, _ in out]
    dupes = sorted({x for x in labels if labels.count(x) > 1})
    if dupes:
        raise ValueError(f"{experiment_path}: two worlds share a name: {dupes}")
    return out


def run_specs(
    exp: Experiment,
    experiment_path: str | Path,
    *,
    seeds: int | None = None,
    quick: bool = False,
    worlds_dir: str | Path | None = None,
    progress: bool = False,
) -> list[RunSpec]:
    """Every run of the grid (scenario x variant x world x source x seed), validated; order:
    seed-major.

    ``seeds`` replaces the experiment's seed count; ``quick`` uses ``exp.quick`` (its seed count
    unless ``seeds`` is given, and its duration). ``worlds_dir``: where generated worlds are
    written (needed when the experiment generates worlds). A run in a world of the world axis
    is named for its scenario and world (``paper_sim@generated_s0100``).
    """
    experiment_path = Path(experiment_path)
    worlds = experiment_worlds(
        exp, experiment_path, Path(worlds_dir) if worlds_dir else None, progress
    )
    if seeds is not None and seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {seeds}")
    n_seeds = seeds if seeds is not None else (exp.quick.seeds if quick else exp.seeds)
    duration_s = exp.quick.duration_s if quick else exp.duration_s
    laps = None if quick else exp.laps
    per_seed: list[list[RunSpec]] = [[] for _ in range(n_seeds)]
    for i, entry in enumerate(exp.scenarios):
        try:
            base = load_scenario(_scenario_path(entry, experiment_path))
        except (ValueError, FileNotFoundError) as exc:
            raise ValueError(f"{experiment_path}: scenarios[{i}]={entry!r}: {exc}") from exc
        if duration_s is not None or laps is not None:
            base = base.with_run_length(laps=laps, duration_s=duration_s)
        for variant in exp.variants or [Variant()]:
            vname = f"{base.name}-{variant.name}" if variant.name else base.name
            for label, world in worlds or [("", "")]:
                base_dict = base.to_dict()
                cell = vname
                if world:  # the world axis: the world's own course, the scenario's settings
                    base_dict.update(world=world, course="")
                    cell = f"{vname}@{label}"
                offset = (
                    variant.floor_offset
                    if variant.floor_offset is not None
                    else exp.worlds.floor_offset
                )
                if offset is not None:
                    base_dict = stated_floor(base_dict, offset, f"{experiment_path}: {cell}")
                for j, src in enumerate(exp.sources):
                    where = (
                        f"{experiment_path}: sources[{j}] ({src.name}) on scenarios[{i}] ({cell})"
                    )
                    merged = apply_overrides(
                        base_dict, exp.overrides, f"{experiment_path}: overrides"
                    )
                    merged = apply_overrides(merged, variant.overrides, f"{where}: variant")
                    merged = apply_overrides(merged, src.overrides, where)
                    checked = scenario_from_yaml_text(yaml.safe_dump(merged), source=where)
                    for k, seed in enumerate(exp.seed_list(n_seeds)):
                        scenario = dataclasses.replace(checked, seed=seed).to_dict()
                        per_seed[k].append(
                            RunSpec(
                                run_id=run_id(cell, src.name, seed),
                                experiment=exp.name,
                                scenario_name=cell,
                                source=src.name,
                                seed=seed,
                                scenario=scenario,
                                spec_hash=spec_hash(scenario),
                                world=label,
                            )
                        )
    specs = [s for group in per_seed for s in group]
    ids = [s.run_id for s in specs]
    dupes = sorted({i for i in ids if ids.count(i) > 1})
    if dupes:
        raise ValueError(
            f"{experiment_path}: two scenarios share a name, so runs collide: {dupes[:3]} "
            "(give each scenario file its own `name`)"
        )
    return specs
