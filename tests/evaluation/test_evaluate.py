"""`pcvfe evaluate`: a tiny grid on an in-process Dask cluster, resume, a failing run, report."""

import json

import numpy as np
import pandas as pd
import pytest
from distributed import LocalCluster

from pcvfe_drake.cli import main
from pcvfe_drake.diagrams.experiment_io import (
    experiment_from_yaml_text,
    load_experiment,
    run_specs,
)
from pcvfe_drake.evaluation.report import build_report
from pcvfe_drake.evaluation.runner import open_client, run_sweep
from pcvfe_drake.evaluation.stats import mean_ci, paired_differences
from pcvfe_drake.evaluation.store import ResultStore
from pcvfe_drake.evaluation.tables import failure_rows, metric_values

TINY = """
name: tiny
scenarios: [paper_sim]
sources:
  - name: pcvfe
  - name: kmpc
    overrides: {nmpc.model: ks}
  - name: broken
    description: a world that does not exist, so building the diagram raises on the worker
    overrides: {world: nowhere}
seeds: 2
duration_s: 3.0
overrides: {camera.noise_std: 2.0}
"""


def collector():
    """An ``on_result`` callback (runs on the client) and the run ids it saw."""
    seen: list[str] = []
    return (lambda spec, result: seen.append(result["run_id"])), seen


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    root = tmp_path_factory.mktemp("evaluate")
    path = root / "tiny.yaml"
    path.write_text(TINY)
    exp, path = load_experiment(path)
    specs = run_specs(exp, path)
    store = ResultStore(root / "out")
    store.start(exp.to_dict(), {"command": "test"})
    on_result, seen = collector()
    with open_client(1, processes=False) as client:
        stats = run_sweep(specs, store, client, on_result=on_result, progress=False)
    return dict(root=root, path=path, specs=specs, store=store, stats=stats, seen=seen)


def test_experiment_errors_name_the_file_and_the_field(tmp_path):
    bad = TINY.replace("overrides: {nmpc.model: ks}", "overrides: {nmpc.model: [ks]}")
    with pytest.raises(ValueError, match=r"exp\.yaml.*sources\[1\]\.overrides\.nmpc\.model"):
        experiment_from_yaml_text(bad, source="exp.yaml")
    with pytest.raises(ValueError, match=r"exp\.yaml.*unknown field 'sources\[0\]\.estimatr'"):
        experiment_from_yaml_text(TINY.replace("- name: pcvfe", "- estimatr: x"), "exp.yaml")
    with pytest.raises(ValueError, match=r"sources\[1\]\.name='pcvfe': used by two sources"):
        experiment_from_yaml_text(TINY.replace("name: kmpc", "name: pcvfe"), "exp.yaml")
    # An override of a field the scenario does not have: the scenario loader names it.
    path = tmp_path / "exp.yaml"
    path.write_text(TINY.replace("nmpc.model: ks", "nmpc.modle: ks"))
    exp, path = load_experiment(path)
    with pytest.raises(ValueError, match=r"sources\[1\] \(kmpc\).*unknown field 'nmpc\.modle'"):
        run_specs(exp, path)
    path.write_text(TINY.replace("nmpc.model: ks", "seed.x: 1"))
    with pytest.raises(ValueError, match=r"override 'seed\.x': 'seed' is not a group"):
        run_specs(*load_experiment(path))


def test_grid_expands_overrides_seeds_and_quick(sweep):
    specs = sweep["specs"]
    assert [s.run_id for s in specs[:3]] == [
        "paper_sim__pcvfe__s000",
        "paper_sim__kmpc__s000",
        "paper_sim__broken__s000",
    ]
    assert len(specs) == 6 and {s.seed for s in specs} == {0, 1}
    by_id = {s.run_id: s for s in specs}
    assert by_id["paper_sim__kmpc__s001"].scenario["nmpc"]["model"] == "ks"
    assert by_id["paper_sim__pcvfe__s001"].scenario["nmpc"]["model"] == "st"
    assert all(s.scenario["camera"]["noise_std"] == 2.0 for s in specs)
    assert all(s.scenario["seed"] == s.seed and s.scenario["duration_s"] == 3.0 for s in specs)
    assert len({s.spec_hash for s in specs}) == 6
    exp, path = load_experiment(sweep["path"])
    quick = run_specs(exp, path, quick=True, seeds=1)
    assert len(quick) == 3 and quick[0].scenario["duration_s"] == exp.quick.duration_s


def test_runs_are_stored_and_a_raising_run_is_recorded(sweep):
    stats, store = sweep["stats"], sweep["store"]
    assert (stats.submitted, stats.done, stats.failed, stats.skipped) == (6, 4, 2, 0)
    assert sorted(sweep["seen"]) == sorted(s.run_id for s in sweep["specs"])
    runs = pd.read_parquet(store.table_path("runs"))
    assert len(runs) == 6
    failed = runs[runs["status"] == "failed"]
    assert set(failed["source"]) == {"broken"}
    assert all("nowhere" in e for e in failed["error"])
    done = runs[runs["status"] == "done"]
    assert np.all(done["sim_time_s"] >= 2.9) and np.all(done["mean_speed_mps"] > 1.0)
    assert np.all(done["task_wall_s"] >= done["sim_wall_s"])
    for r in done.itertuples():
        folder = store.run_dir(r.run_id)
        summary = json.loads((folder / "summary.json").read_text())
        assert summary["seed"] == r.seed and summary["mean_speed_mps"] == r.mean_speed_mps
        log = pd.read_parquet(folder / "drive_log.parquet")
        assert log["t"].iloc[-1] == pytest.approx(3.0, abs=0.06)
        assert len(failure_rows(summary)) == summary["catastrophic_failures"]
    for r in failed.itertuples():
        assert "Traceback" in (store.run_dir(r.run_id) / "error.txt").read_text()
    laps = pd.read_parquet(store.table_path("laps"))
    assert set(laps["run_id"]) == set(done["run_id"])
    assert np.all(~laps["complete"]) and np.all(laps["mean_speed_mps"] > 1.0)
    # The KMPC tracks worse than the friction-aware NMPC, seed by seed.
    diff = paired_differences(done, "lateral_error_rms_m", "pcvfe")
    assert len(diff) == 2 and np.all(diff["diff"] > 0)


def test_resume_skips_finished_runs_and_retries_failed_ones(sweep):
    store = ResultStore(sweep["store"].root)
    before = pd.read_parquet(store.table_path("runs")).set_index("run_id")
    on_result, seen = collector()
    with open_client(1, processes=False) as client:
        stats = run_sweep(sweep["specs"], store, client, on_result=on_result, progress=False)
    assert stats.skipped == 4 and stats.submitted == 2
    assert sorted(seen) == ["paper_sim__broken__s000", "paper_sim__broken__s001"]
    after = pd.read_parquet(store.table_path("runs")).set_index("run_id")
    assert len(after) == 6
    done = before.index[before["status"] == "done"]
    assert (after.loc[done, "finished_utc"] == before.loc[done, "finished_utc"]).all()


def test_report_from_stored_tables(sweep, tmp_path):
    store = sweep["store"]
    md, html = build_report(store.root)
    text = md.read_text()
    assert "| pcvfe | 2 |" in text and "| kmpc | 2 |" in text
    assert "| broken | 0 (+2 failed) |" in text
    assert "Paired difference to pcvfe" in text and "## Failed runs" in text
    assert "nmpc.model: ks" in text and "drake" in text
    for fig in ("speed_failures.png", "mu_over_time.png", "failure_map.png"):
        assert (store.figures / fig).stat().st_size > 5000
    page = html.read_text()
    assert page.count("data:image/png;base64,") == 3 and "<table>" in page
    # The command rebuilds it from the folder alone.
    md.unlink()
    assert main(["evaluate", "--report", str(store.root)]) == 0
    assert md.read_text() == text
    assert main(["evaluate", "--report", str(tmp_path)]) == 2  # no tables there


def test_cli_runs_on_a_scheduler_by_address_and_resumes(tmp_path, capsys):
    path = tmp_path / "two.yaml"
    path.write_text(
        "name: two\nsources: [{name: pcvfe}]\nseeds: 2\nduration_s: 2.0\n"
        "quick: {seeds: 1, duration_s: 1.0}\n"
    )
    out = tmp_path / "out"
    local = dict(dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, **local) as cluster:
        address = cluster.scheduler_address
        args = ["evaluate", str(path), "--out", str(out), "--scheduler", address, "--no-progress"]
        assert main(args) == 0
        assert "2 to run" in capsys.readouterr().out
        assert main(args) == 0
        assert "2 already done" in capsys.readouterr().out
    assert (out / "report.html").is_file()
    assert len(pd.read_parquet(out / "runs.parquet")) == 2


def test_mean_ci_and_paired_differences_by_hand():
    ci = mean_ci([1.0, 2.0, 3.0, np.nan])
    # mean 2, sd 1, t(0.975, 2) = 4.3027
    assert ci.n == 3 and ci.mean == 2.0
    assert ci.half_width == pytest.approx(4.302653 / np.sqrt(3), rel=1e-5)
    assert np.isnan(mean_ci([5.0]).lo) and mean_ci([]).n == 0
    runs = pd.DataFrame(
        {
            "source": ["a", "a", "b", "b", "b"],
            "seed": [0, 1, 0, 1, 2],
            "v": [1.0, 2.0, 1.5, 1.0, 9.0],
        }
    )
    d = paired_differences(runs, "v", "a")
    assert d["seed"].tolist() == [0, 1] and d["diff"].tolist() == [0.5, -1.0]


def test_metrics_and_failures_read_from_either_summary_layout():
    old = {
        "mu_error_after_settle": {"worst_mean": 0.1},
        "failure_events": [{"t_s": 3.0, "sx_m": 1.0, "sy_m": 2.0, "kind": "spin"}],
    }
    new = {
        "mu_error_after_entry": {"mean": 0.2},
        "transition_response": {"median_s": 1.5},
        "failures": [{"t_s": 3.0, "x_m": 1.0, "y_m": 2.0, "s_m": 5.0, "reason": "spin"}],
    }
    assert metric_values(old)["mu_error_settled"] == 0.1
    assert metric_values(new)["mu_error_settled"] == 0.2
    assert metric_values(new)["transition_response_s"] == 1.5
    assert np.isnan(metric_values(old)["transition_response_s"])
    assert (
        failure_rows(old)
        == failure_rows(new)
        == [{"t_s": 3.0, "sx_m": 1.0, "sy_m": 2.0, "kind": "spin"}]
    )


def test_shipped_experiments_load_and_expand():
    from pcvfe_drake.evaluation.experiment import shipped_experiments

    assert "paper_claim3" in shipped_experiments()
    exp, path = load_experiment("paper_claim3")
    names = ["pcvfe_paper", "ukf", "lookup", "fixed", "kmpc", "oracle"]
    assert [s.name for s in exp.sources] == names
    specs = run_specs(exp, path)
    assert len(specs) == 60 and {s.scenario_name for s in specs} == {"paper_eval"}
    estimators = {s.source: s.scenario["estimator"] for s in specs}
    assert estimators == {s.name: s.name for s in exp.sources}
    assert all(s.scenario["laps"] == 1.0 for s in specs)


def test_binary_experiment_file_is_named(tmp_path):
    path = tmp_path / "grid.yaml"
    path.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(ValueError, match=r"grid\.yaml: not an experiment file \(not UTF-8"):
        load_experiment(path)


def test_shutdown_drops_only_the_nannys_kill_message():
    import logging

    from pcvfe_drake.evaluation.runner import _DropMessage

    quiet = _DropMessage("still alive after")

    def record(msg):
        return logging.LogRecord("distributed.nanny", logging.WARNING, __file__, 1, msg, (), None)

    assert not quiet.filter(record("Worker process still alive after 4.0 seconds, killing"))
    assert quiet.filter(record("Restarting worker"))


def test_terrain_rows_count_settled_and_covered_pairs_by_hand():
    from pcvfe_drake.evaluation.tables import terrain_rows

    contexts = pd.DataFrame(
        {
            "scenario": ["s"] * 5,
            "source": ["a", "a", "a", "a", "b"],
            "majority_terrain": ["sand", "sand", "sand", "grass", "sand"],
            "true_mu": [0.45, 0.45, 0.45, 0.3, 0.45],
            "mu_hat": [0.44, 0.30, 0.41, 0.31, 0.5],
            "abs_error_after_settle_max": [0.01, 0.15, None, 0.05, 0.06],
            "covered_95": [True, False, True, None, True],
        }
    )
    rows = {(r["source"], r["terrain"]): r for r in terrain_rows(contexts)}
    sand = rows[("a", "sand")]
    assert (sand["pairs"], sand["scored"], sand["within"]) == (3, 2, 1)
    assert (sand["interval_known"], sand["covered"]) == (3, 2)
    assert (sand["mu_hat_min"], sand["mu_hat_max"]) == (0.30, 0.44)
    grass = rows[("a", "grass")]
    assert (grass["within"], grass["scored"], grass["interval_known"]) == (1, 1, 0)
    assert rows[("b", "sand")]["within"] == 0
    # Results stored before covered_95 existed: no interval counts, the rest as before.
    old = terrain_rows(contexts.drop(columns="covered_95"))
    assert all(r["interval_known"] == 0 for r in old) and len(old) == 3
    assert terrain_rows(pd.DataFrame()) == []


def test_variants_run_every_scenario_once_per_variant(tmp_path):
    path = tmp_path / "cars.yaml"
    path.write_text(
        "name: cars\nscenarios: [paper_eval]\nseeds: 1\n"
        "variants:\n"
        "  - {name: bmw, overrides: {vehicle: bmw_320i}}\n"
        "  - {name: van-project, overrides: {vehicle: vw_vanagon,\n"
        "                                    friction_mapping: peak_and_stiffness}}\n"
        "sources:\n  - {name: oracle, overrides: {estimator: oracle}}\n"
    )
    exp, _ = load_experiment(path)
    specs = run_specs(exp, path)
    assert [s.scenario_name for s in specs] == ["paper_eval-bmw", "paper_eval-van-project"]
    assert [s.run_id for s in specs] == [
        "paper_eval-bmw__oracle__s000",
        "paper_eval-van-project__oracle__s000",
    ]
    assert [(s.scenario["vehicle"], s.scenario["friction_mapping"]) for s in specs] == [
        ("bmw_320i", "lateral_peak"),
        ("vw_vanagon", "peak_and_stiffness"),
    ]
    path.write_text(path.read_text().replace("name: van-project", "name: bmw"))
    with pytest.raises(ValueError, match=r"variants\[1\].name='bmw': used by two variants"):
        load_experiment(path)
