"""The tables of ``pcvfe evaluate --report DIR``: entry latency, interval coverage and the
results page, on small synthetic run folders and results tables with known answers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pcvfe_drake.cli import main
from pcvfe_drake.control.course import load_course
from pcvfe_drake.evaluation import interval_coverage as ic
from pcvfe_drake.evaluation.entry_latency import experiment_entries, run_entries, terrain_lag
from pcvfe_drake.evaluation.results_page import (
    experiment_section,
    page_folders,
    update_results_page,
)
from pcvfe_drake.runs.drivelog import TRUE_STATE_COLUMNS
from pcvfe_drake.vehicle.single_track import STATE_NAMES

COURSE = load_course("slalom")


def _run_folder(
    folder, speed_mps: float, seed: int, *, enter_s: float = 5.0, course=COURSE
) -> None:
    """A run along the course's centre line at ``speed_mps``: sand until ``enter_s``, then
    brick; brick's context 1 is reported 2 s after the entry, first fitted at 3 s, and the
    handed mu reaches the truth at 4 s (times scaled by nothing: the log's own clock)."""
    folder.mkdir(parents=True)
    t = np.arange(0.0, 12.0, 0.05)
    s = speed_mps * t
    x = np.interp(s, np.arange(course.n) * course.ds, course.x)
    y = np.interp(s, np.arange(course.n) * course.ds, course.y)
    psi = np.interp(s, np.arange(course.n) * course.ds, course.heading)
    state = {"sx": x, "sy": y, "delta": 0 * t, "v": 0 * t + speed_mps, "psi": psi}
    state |= {"psi_dot": 0 * t, "beta": 0 * t}
    log = pd.DataFrame({"t": t, **state})
    for name, true_name in zip(STATE_NAMES, TRUE_STATE_COLUMNS, strict=True):
        log[true_name] = log[name]
    brick = t >= enter_s
    log["terrain"] = np.where(brick, "brick", "sand")
    log["mu_true"] = np.where(brick, 0.8, 0.45)
    log["mu_hat"] = np.where(t >= enter_s + 4.0, 0.8, 0.45)
    log["context"] = np.where(brick & (t < enter_s + 2.0), -1, np.where(brick, 1, 0))
    log.to_parquet(folder / "drive_log.parquet")
    summary = {
        "seed": seed,
        "mean_speed_mps": speed_mps,
        "lap_time_s": None,
        "catastrophic_failures": 0,
        "mu_estimates": [
            {"id": 0, "first_fit_s": 1.0},
            {"id": 1, "first_fit_s": enter_s + 3.0},
        ],
    }
    (folder / "summary.json").write_text(json.dumps(summary))
    (folder / "scenario.yaml").write_text(yaml.safe_dump({"course": "slalom", "seed": seed}))


def test_entry_latency_and_the_time_lost_at_the_same_arc_length(tmp_path):
    runs = tmp_path / "exp" / "runs"
    for seed in (0, 1):
        _run_folder(runs / f"paper_eval__pcvfe__s{seed:03d}", 4.0, seed)
        _run_folder(runs / f"paper_eval__oracle__s{seed:03d}", 8.0, seed, enter_s=2.5)
    entry = run_entries(runs / "paper_eval__pcvfe__s000")
    (brick,) = entry["entries"]
    assert brick["terrain"] == "brick" and brick["t_enter_s"] == 5.0
    assert (brick["id"], brick["fit"], brick["within"]) == (2.0, 3.0, 4.0)
    assert brick["lat"] < 1e-6  # on the centre line
    # Twice as fast over the same course: each visit took twice the reference's time.
    lag = terrain_lag(runs / "paper_eval__pcvfe__s000", runs / "paper_eval__oracle__s000")
    assert lag["speed_ratio"] == 0.5
    sand = next(v for v in lag["visits"] if v["terrain"] == "sand")
    assert sand["lag_s"] == pytest.approx(sand["run_s"] / 2, abs=0.06)
    assert "lag_first_s" not in sand  # only asked for with splits
    # Cut in the visit's first seconds: half of them lost too; a split beyond the visit: all
    split = terrain_lag(
        runs / "paper_eval__pcvfe__s000", runs / "paper_eval__oracle__s000", [1, 99]
    )
    cut = next(v for v in split["visits"] if v["terrain"] == "sand")
    assert cut["lag_first_s"]["1"] == pytest.approx(0.5, abs=0.06)
    assert cut["lag_first_s"]["99"] == cut["lag_s"] == sand["lag_s"]
    result = experiment_entries(tmp_path / "exp", against="oracle")
    group = result["groups"]["paper_eval / pcvfe"]
    assert group["per_terrain"]["brick"]["within_mean_s"] == 4.0
    assert group["per_terrain"]["brick"]["lag_per_run_mean_s"] > 0
    assert "paper_eval / oracle" not in result["groups"]
    with pytest.raises(ValueError, match="--against kmpc"):
        experiment_entries(tmp_path / "exp", against="kmpc")


def test_a_run_on_a_generated_world_is_measured_along_the_worlds_own_course(tmp_path):
    """A generated world brings its course (the run's scenario names none): the lateral error
    and the progress are taken along that course, not the default one."""
    from pcvfe_drake.evaluation.entry_latency import run_course
    from pcvfe_drake.vehicle.params import ford_escort
    from pcvfe_drake.worlds.generate import write_generated_world

    world_path, _ = write_generated_world(3, ford_escort(), tmp_path / "worlds")
    course = run_course({"world": str(world_path), "course": ""})
    assert course.length != pytest.approx(load_course(None).length)
    folder = tmp_path / "run"
    _run_folder(folder, 4.0, 0, course=course)
    (folder / "scenario.yaml").write_text(yaml.safe_dump({"world": str(world_path), "course": ""}))
    (brick,) = run_entries(folder)["entries"]
    assert brick["lat"] < 1e-6  # on the world's centre line


def test_entry_latency_needs_run_folders(tmp_path):
    with pytest.raises(FileNotFoundError, match="no finished runs"):
        experiment_entries(tmp_path)
    (tmp_path / "r").mkdir()
    with pytest.raises(FileNotFoundError, match="summary.json"):
        run_entries(tmp_path / "r")


def _row(seed, mu, std, true_mu, near=True, kind="effects"):
    fit = {"mu": mu, "std_data": std, "near_limit": near}
    return {
        "kind": kind,
        "seed": seed,
        "true_mu": true_mu,
        "live_covered": True,
        "live_near_limit": near,
        "live_mu": mu,
        "live_std_data": std,
        "mu_lower_bound": 0.5 * true_mu,
        "upper": 1.5,
        "iid": dict(fit),
        "hac": dict(fit),
    }


def test_interval_calibration_and_coverage_by_hand():
    # Each pair needs the budget |mu - true| / 1.96 / mu (std 0): 0.05, 0.095 and 0.20.
    rows = [
        _row(seed, mu, 0.0, mu * (1 + 1.959964 * rel))
        for seed, mu, rel in ((0, 0.5, 0.05), (1, 0.6, 0.095), (2, 0.4, 0.20))
    ]
    rows.append(_row(7, 0.5, 0.0, 0.5 * (1 + 1.959964 * 0.11)))  # held out
    rows.append(_row(8, 0.3, 0.0, 0.9, near=False))  # one-sided: [0.45, 1.5] holds 0.9
    cal = ic.calibrate(rows, {0, 1, 2}, target=2 / 3)
    assert cal["pairs"] == 3 and cal["needed_rel"] == pytest.approx([0.05, 0.095, 0.20])
    assert cal["rel"] == 0.10  # the 2/3 quantile, rounded up to 0.01
    cov = ic.score(rows, cal["rel"], {0, 1, 2}, two_sided=False)["effects"]
    assert cov["calibration"]["hac"]["covered"] == 2  # the 0.20 pair stays out
    assert cov["held_out"]["hac"]["covered"] == 1  # [0.5 +- 0.098] misses the truth 0.554 ...
    assert cov["held_out"]["pairs"] == 2 and cov["held_out"]["hac"]["two_sided_pairs"] == 1
    two = ic.score(rows, cal["rel"], {0, 1, 2}, two_sided=True)["effects"]["held_out"]["hac"]
    assert two["covered"] == 0  # ... and two-sided, seed 8's 0.3 +- 0 misses 0.9 too
    with pytest.raises(ValueError, match="no near-limit st pairs"):
        ic.calibrate(rows, {0, 1, 2}, on="st")
    assert ic.parse_seeds("0-2,7") == {0, 1, 2, 7}
    with pytest.raises(ValueError, match="'x'"):
        ic.parse_seeds("0-2,x")


def _store(root, worlds: bool = False, world_in_name: bool = False) -> None:
    """A tiny results folder: two sources x three seeds (x two worlds, each its own scenario
    ``paper_eval@WORLD`` with ``world_in_name``, as generated worlds are), numbers by hand."""
    root.mkdir(parents=True)
    rows = []
    for seed in (0, 1, 2):
        for world in ("w_flat", "w_hills") if worlds else (None,):
            slow = world == "w_hills"
            for source, speed in (("pcvfe", 6.0 + 0.1 * seed), ("oracle", 7.0 + 0.1 * seed)):
                rows.append(
                    {
                        "run_id": f"s__{source}__s{seed:03d}",
                        "scenario": f"paper_eval@{world}" if world_in_name else "paper_eval",
                        "source": source,
                        "seed": seed,
                        "spec_hash": f"h{seed}",
                        "status": "done",
                        "error": "",
                        "versions": "numpy 2.0.0",
                        "mean_speed_mps": speed - (1.0 if slow else 0.0),
                        "lap_time_s": 120.0,
                        "failures": float(slow and source == "pcvfe" and seed == 0),
                        "lateral_error_rms_m": 0.05,
                        "mu_error": 0.01,
                        **({"world": world} if world else {}),
                    }
                )
    pd.DataFrame(rows).to_parquet(root / "runs.parquet")
    exp = {
        "name": "tiny",
        "description": "a tiny grid",
        "scenarios": ["paper_eval"],
        "sources": [
            {"name": "pcvfe", "description": "ours", "overrides": {"estimator": "pcvfe"}},
            {"name": "oracle", "description": "truth", "overrides": {"estimator": "oracle"}},
        ],
        "reference": "pcvfe",
        "seeds": 3,
        "first_seed": 0,
        "laps": 1,
    }
    (root / "experiment.yaml").write_text(yaml.safe_dump(exp))
    env = {"command": "pcvfe evaluate tiny --seeds 3", "started_utc": "2026-01-01T00:00:00Z"}
    env["client_versions"] = {"pcvfe-drake": "0.3.0", "numpy": "2.0.0"}
    (root / "environment.json").write_text(json.dumps(env))


def test_results_page_from_stored_tables(tmp_path):
    _store(tmp_path / "a")
    key, text = experiment_section(tmp_path / "a")
    assert "Made by `pcvfe evaluate tiny --seeds 3`" in text
    assert (
        "pcvfe-drake 0.3.0" in text
        and "source **oracle**: truth (`{'estimator': 'oracle'}`)" in text
    )
    # 6.0, 6.1, 6.2: mean 6.1, t(2) 4.303 * 0.1 / sqrt(3) = 0.248
    assert "| pcvfe | 3 | 6.1 [5.85, 6.35] |" in text
    assert "| oracle | 3 | 7.1 [6.85, 7.35] |" in text and "| 1 [1, 1] |" in text
    assert "median world" not in text
    page = tmp_path / "results.md"
    update_results_page(page, [tmp_path / "a"])
    _store(tmp_path / "b", worlds=True)
    update_results_page(page, [tmp_path / "b"])
    update_results_page(page, [tmp_path / "a"])  # rewrites a's section in place
    out = page.read_text()
    assert out.count("## tiny") == 2 and out.index(key) < out.index(str(tmp_path / "b"))
    assert "| pcvfe | 2 | w_flat: 6.1 m/s, 0 failures per run | w_hills: 5.1 m/s, 0.333" in out


def test_a_scenario_named_per_world_is_one_table_over_its_worlds(tmp_path):
    _store(tmp_path / "c", worlds=True, world_in_name=True)
    _, text = experiment_section(tmp_path / "c")
    assert text.count("### ") == 1 and "### paper_eval\n" in text and "@w_" not in text
    assert "| pcvfe | 6 |" in text  # three seeds on each of the two worlds
    # paired by seed and world: oracle minus pcvfe is 1.0 in each of the six pairs
    assert "| 1 [1, 1] |" in text
    assert "| pcvfe | 2 | w_flat: 6.1 m/s, 0 failures per run | w_hills: 5.1 m/s, 0.333" in text


def test_report_options_from_the_command_line(tmp_path, capsys):
    _store(tmp_path / "a")
    runs = tmp_path / "a" / "runs"
    for seed in (0, 1, 2):
        _run_folder(runs / f"paper_eval__pcvfe__s{seed:03d}", 4.0, seed)
    page = tmp_path / "docs" / "results.md"
    code = main(
        [
            "evaluate",
            "--report",
            str(tmp_path / "a"),
            "--entry-latency",
            "--results-page",
            str(page),
        ]
    )
    assert code == 0
    assert "| brick | 3 | 2.0 | 3.0 | 4.0 |" in (tmp_path / "a" / "entry_latency.md").read_text()
    assert "## tiny" in page.read_text()
    assert main(["evaluate", "paper_sim", "--entry-latency"]) == 2
    assert "go with --report DIR" in capsys.readouterr().err


def test_the_projects_results_page_is_generated_from_its_stored_tables(tmp_path, monkeypatch):
    """docs/results.md is exactly what its stored experiment folders give: never hand-edited."""
    root = Path(__file__).resolve().parents[2]
    monkeypatch.chdir(root)
    folders = page_folders("docs/results.md")
    assert folders, "docs/results.md names no stored experiment"
    regenerated = update_results_page(tmp_path / "results.md", folders).read_text()
    regenerated = regenerated.replace((tmp_path / "results.md").as_posix(), "docs/results.md")
    assert regenerated == (root / "docs" / "results.md").read_text()


def test_sources_restrict_the_grid_and_name_an_unknown_one():
    from pcvfe_drake.evaluation.experiment import Experiment, Source

    exp = Experiment(
        name="g",
        sources=[Source(name=n) for n in ("pcvfe", "ukf", "oracle")],
        reference="pcvfe",
    )
    part = exp.with_sources(["oracle", "ukf"])
    assert [s.name for s in part.sources] == ["ukf", "oracle"]  # the experiment's order
    assert part.reference_source == "ukf"  # the reference was left out: the first kept
    assert exp.with_sources(["pcvfe", "oracle"]).reference_source == "pcvfe"
    with pytest.raises(ValueError, match="unknown source.*kmpc.*its sources: pcvfe, ukf, oracle"):
        exp.with_sources(["kmpc"])


def test_refit_of_a_run_folders_final_buffer(tmp_path):
    """A run on the ST truth (mu 0.6, 20 s S-curves, noise-free): the refit of the context's
    buffer finds mu, the row carries the run's own estimate and the truth."""
    from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
    from pcvfe_drake.vehicle.params import ford_escort

    t, states, inputs = s_curve_drive(ford_escort(), [0.6], duration_s=20.0)
    log = drive_frame(t, states[0], inputs[0])
    log["final_context"] = 0
    folder = tmp_path / "paper_sim__pcvfe__s003"
    folder.mkdir()
    log.to_parquet(folder / "drive_log.parquet")
    estimate = {"id": 0, "majority_terrain": "concrete", "true_mu": 0.6, "mu_hat": 0.59}
    estimate |= {"std": 0.01, "covered_95": True, "near_limit": True}
    (folder / "summary.json").write_text(json.dumps({"seed": 3, "mu_estimates": [estimate]}))
    fitter = {"buffer_s": 60.0, "horizon_steps": 10, "stride_steps": 5, "min_windows": 20}
    fitter |= {"max_windows": 512, "near_limit_fraction": 0.6, "effects": []}
    scenario = {"vehicle": "ford_escort", "seed": 3, "fitter": fitter}
    (folder / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    (row,) = ic.refit_run(folder)
    assert row["kind"] == "st" and row["seed"] == 3 and row["terrain"] == "concrete"
    assert row["hac"]["mu"] == pytest.approx(0.6, abs=0.01)
    assert row["iid"]["mu"] == pytest.approx(row["hac"]["mu"], abs=1e-6)  # one fit, two stds
    assert row["live_mu"] == 0.59 and row["live_std_data"] == pytest.approx(0.01)
    assert row["mu_lower_bound"] > 0.1
