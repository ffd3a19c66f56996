"""`pcvfe evaluate` over worlds: listed and generated worlds make a world axis, and the report
gives each source's median and worst world (a tiny grid on an in-process Dask cluster)."""

from pathlib import Path

import pandas as pd
import pytest

from pcvfe_drake.diagrams.experiment_io import experiment_from_yaml_text, load_experiment, run_specs
from pcvfe_drake.evaluation.report import build_report
from pcvfe_drake.evaluation.runner import open_client, run_sweep
from pcvfe_drake.evaluation.store import ResultStore

WORLDS = """
name: worlds
scenarios: [roboracer]
sources:
  - name: oracle
    overrides: {estimator: oracle}
  - name: fixed
    overrides: {estimator: fixed}
seeds: 1
duration_s: 1.5
worlds:
  names: [paper_small]
  generate: {count: 2, seed: 100, mu_range: [0.3, 0.9], terrains: 3}
"""


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    root = tmp_path_factory.mktemp("evaluate_worlds")
    path = root / "worlds.yaml"
    path.write_text(WORLDS)
    exp, path = load_experiment(path)
    specs = run_specs(exp, path, worlds_dir=root / "out" / "worlds")
    store = ResultStore(root / "out")
    store.start(exp.to_dict(), {"command": "test"})
    with open_client(1, processes=False) as client:
        stats = run_sweep(specs, store, client, progress=False)
    return dict(root=root, specs=specs, store=store, stats=stats)


def test_the_grid_is_world_by_source_by_seed(sweep):
    specs = sweep["specs"]
    worlds = ["paper_small", "generated_s0100", "generated_s0101"]
    assert sorted({s.world for s in specs}) == sorted(worlds)
    assert len(specs) == 3 * 2 * 1
    assert {s.run_id for s in specs} >= {"roboracer-generated_s0100__oracle__s000"}
    by_world = {s.world: s.scenario for s in specs if s.source == "oracle"}
    assert by_world["paper_small"]["world"] == "paper_small"
    generated = by_world["generated_s0100"]["world"]
    assert (
        generated.endswith("worlds/generated_s0100.yaml")
        and by_world["paper_small"]["course"] == ""
    )
    assert (sweep["root"] / "out" / "worlds" / "generated_s0101_course.yaml").is_file()


def test_runs_are_stored_per_world_and_the_report_gives_median_and_worst_world(sweep):
    assert sweep["stats"].failed == 0
    runs = sweep["store"].table("runs")
    assert set(runs["world"]) == {"paper_small", "generated_s0100", "generated_s0101"}
    md, _ = build_report(sweep["store"].root)
    text = md.read_text()
    # one section for the scenario over its worlds, not one per world
    assert text.count("## Scenario ") == 1 and "## Scenario roboracer\n" in text
    assert "### Over its 3 worlds" in text and "same seed and world" in text
    assert "each on 3 worlds" in text
    for world in ("paper_small", "generated_s0100", "generated_s0101"):
        assert f"| {world} | " in text  # its row of the per-world speeds
    speed = {r["source"]: r for r in _world_rows(runs, "mean_speed_mps")}
    per_world = runs[runs["source"] == "oracle"].groupby("world")["mean_speed_mps"].mean()
    assert speed["oracle"]["worst_world"] == per_world.idxmin()
    assert speed["oracle"]["median"] == pytest.approx(per_world.median())
    assert f"| oracle | 3 | {_fmt(per_world.median())} |" in text.replace(
        "mean speed [m/s] (higher is better) ", ""
    )


def test_worlds_the_oracle_fails_are_named_in_the_report():
    from pcvfe_drake.evaluation.report import _Doc, _worlds_section, oracle_failed_worlds
    from pcvfe_drake.evaluation.tables import METRICS

    rows = [
        ("w1", "oracle", 0, "done", 9.0), ("w1", "pcvfe", 0, "done", 8.5),
        ("w2", "oracle", 1, "done", 7.0), ("w2", "pcvfe", 1, "done", 6.0),
        ("w3", "oracle", 0, "error", None), ("w3", "pcvfe", 2, "done", 5.0),
    ]  # fmt: skip
    runs = pd.DataFrame(rows, columns=["world", "source", "failures", "status", "mean_speed_mps"])
    assert oracle_failed_worlds(runs) == ["w2"]  # a run that did not finish says nothing
    assert oracle_failed_worlds(runs[runs["source"] != "oracle"]) == []
    doc = _Doc()
    metric = next(m for m in METRICS if m.column == "mean_speed_mps")
    _worlds_section(doc, runs, ["oracle", "pcvfe"], [metric])
    text = " ".join(b[1] for b in doc.blocks if b[0] == "p")
    assert "The oracle itself failed in 1 world: w2." in text


def test_a_scenario_over_worlds_is_one_group_and_its_estimates_are_summed():
    from pcvfe_drake.evaluation.report import _Doc, _terrain_totals, scenario_groups

    runs = pd.DataFrame(
        {"scenario": ["a@w1", "a@w2", "b@w1", "c"], "world": ["w1", "w2", "w1", ""]}
    )
    assert list(scenario_groups(runs)) == ["a", "a", "b", "c"]
    assert list(scenario_groups(runs.drop(columns="world"))) == list(runs["scenario"])
    row = dict(pairs=2, within=1, scored=2, covered=2, interval_known=2)
    rows = [
        {**row, "source": "pcvfe", "scenario": "a@w1"},
        {**row, "source": "pcvfe", "scenario": "a@w2", "within": 0},
        {**row, "source": "lookup", "scenario": "a@w1", "interval_known": 0, "covered": 0},
    ]
    doc = _Doc()
    _terrain_totals(doc, rows, ["pcvfe", "lookup"])
    table = next(b for b in doc.blocks if b[0] == "table")
    assert table[2] == [
        ["pcvfe", "4", "1 of 4 (0.25)", "4 of 4 (1.00)"],
        ["lookup", "2", "1 of 2 (0.50)", "-"],
    ]


def _world_rows(runs: pd.DataFrame, column: str):
    from pcvfe_drake.evaluation.report import world_table
    from pcvfe_drake.evaluation.tables import METRICS

    metric = next(m for m in METRICS if m.column == column)
    return world_table(runs, metric, ["oracle", "fixed"])


def _fmt(x):
    from pcvfe_drake.evaluation.report import fmt_number as fmt

    return fmt(x)


def test_bad_world_settings_are_named(tmp_path):
    bad = WORLDS.replace("count: 2", "count: 0")
    with pytest.raises(ValueError, match=r"worlds.generate.count=0: must be an integer >= 1"):
        experiment_from_yaml_text(bad, "exp.yaml")
    bad = WORLDS.replace("names: [paper_small]", "names: [atlantis]")
    path = tmp_path / "exp.yaml"
    path.write_text(bad)
    exp, path = load_experiment(path)
    with pytest.raises(ValueError, match=r"worlds.names\[0\]: world 'atlantis' is neither"):
        run_specs(exp, path, worlds_dir=tmp_path / "w")


FLOOR = """
name: floor
scenarios: [paper_eval]
variants:
  - {name: stated}
  - {name: above, floor_offset: 0.1}
  - {name: fixed, floor_offset: 0.1, overrides: {fixed.conservative_mu: 0.5}}
sources:
  - name: fixed
    overrides: {estimator: fixed}
seeds: 1
duration_s: 1.0
worlds:
  names: [paper_small]
  generate: {count: 1, seed: 100, mu_range: [0.2, 0.9], terrains: 3}
  floor_offset: -0.1
"""


def test_the_stated_floor_follows_each_world_s_lowest_friction(tmp_path):
    """floor_offset gives every run the floor its own world implies; a variant's offset
    replaces the worlds', and an explicit override of the value still wins."""
    from pcvfe_drake.diagrams.world_io import load_world
    from pcvfe_drake.worlds.world_file import lowest_mu

    path = tmp_path / "floor.yaml"
    path.write_text(FLOOR)
    exp, path = load_experiment(path)
    specs = run_specs(exp, path, worlds_dir=tmp_path / "worlds")
    generated_low = lowest_mu(load_world(tmp_path / "worlds" / "generated_s0100.yaml")[0])
    lows = {"paper_small": 0.3, "generated_s0100": generated_low}
    assert 0.2 <= generated_low <= 0.9
    for s in specs:
        variant = s.scenario_name.split("@")[0].rsplit("-", 1)[1]
        offset = 0.1 if variant != "stated" else -0.1
        floor = pytest.approx(max(0.05, lows[s.world] + offset), abs=1e-6)
        assert s.scenario["fitter"]["handing"]["floor_mu"] == floor
        expected_fixed = 0.5 if variant == "fixed" else floor
        assert s.scenario["fixed"]["conservative_mu"] == expected_fixed
    assert len(specs) == 3 * 2


def test_a_terrain_override_moves_the_lowest_friction():
    from pcvfe_drake.diagrams.experiment_io import stated_floor
    from pcvfe_drake.diagrams.world_io import load_world
    from pcvfe_drake.runs.scenario import Scenario
    from pcvfe_drake.worlds.world_file import lowest_mu

    spec, _ = load_world("paper_small")
    assert lowest_mu(spec) == 0.3

    def floor(terrains):
        scenario = dict(Scenario().to_dict(), world="paper_small", terrains=terrains)
        return stated_floor(scenario, 0.0, "test")["fitter"]["handing"]["floor_mu"]

    assert floor({"patchy_grass": {"mu": 0.22}}) == 0.22
    assert floor({"patchy_grass": {"mu": 0.9}}) == 0.45


def test_a_bad_floor_offset_is_named():
    bad = FLOOR.replace("floor_offset: -0.1", "floor_offset: 2")
    with pytest.raises(ValueError, match=r"worlds.floor_offset=2.0: must be a number in \[-1, 1\]"):
        experiment_from_yaml_text(bad, "exp.yaml")
    bad = FLOOR.replace("{name: above, floor_offset: 0.1}", "{name: above, floor_offset: .nan}")
    with pytest.raises(ValueError, match=r"variants\[1\].floor_offset=nan"):
        experiment_from_yaml_text(bad, "exp.yaml")


def test_a_results_folder_moved_elsewhere_resumes_with_nothing_to_run(sweep, tmp_path):
    """A run's identity holds a generated world by its content, not its path: the folder
    copied to another place (another machine) plans the same runs, all done."""
    import shutil

    from pcvfe_drake.evaluation.experiment import spec_hash

    moved = tmp_path / "moved"
    shutil.copytree(sweep["store"].root, moved)
    exp, path = load_experiment(sweep["root"] / "worlds.yaml")
    specs = run_specs(exp, path, worlds_dir=moved / "worlds")
    assert all(str(moved) in s.scenario["world"] for s in specs if "generated" in s.world)
    assert ResultStore(moved).pending(specs) == []
    # a world whose content changed is another run
    spec = next(s for s in specs if "generated" in s.world)
    world = Path(spec.scenario["world"])
    world.write_text(world.read_text().replace("mu: ", "mu: 0", 1))
    assert spec_hash(spec.scenario) != spec.spec_hash
