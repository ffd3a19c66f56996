"""`pcvfe evaluate --report` on damaged results folders: a file it cannot read is one error naming
it (exit 2); a run's missing or damaged drive log or scenario is drawn around, and said."""

from __future__ import annotations

import io
import shutil

import numpy as np
import pandas as pd
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.evaluation.store import ResultStore


def _summary(speed: float) -> dict:
    return {
        "sim_time_s": 5.0,
        "wall_time_s": 1.0,
        "laps_completed": 0,
        "mean_speed_mps": speed,
        "catastrophic_failures": 0,
        "failure_events": [],
    }


def _drive_log(seed: int) -> bytes:
    t = np.arange(50) * 0.1
    frame = pd.DataFrame({"t": t, "mu_hat": 0.5 + 0.01 * seed + 0 * t, "mu_true": 0.5 + 0 * t})
    buffer = io.BytesIO()
    frame.to_parquet(buffer)
    return buffer.getvalue()


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A results folder of four runs (two sources x two seeds) written the way the runner does."""
    store = ResultStore(tmp_path_factory.mktemp("ev") / "results")
    store.start({"name": "tiny", "sources": [{"name": "pcvfe"}, {"name": "fixed"}]}, {"x": 1})
    for source in ("pcvfe", "fixed"):
        for seed in (0, 1):
            spec = {
                "run_id": f"paper_sim__{source}__s00{seed}",
                "experiment": "tiny",
                "scenario_name": "paper_sim",
                "source": source,
                "seed": seed,
                "spec_hash": "h",
                "scenario": {"name": "paper_sim", "course": "slalom"},
            }
            result = {
                "status": "done",
                "summary": _summary(5.0 + seed),
                "drive_log_parquet": _drive_log(seed),
            }
            store.record(spec, result)
    assert main(["evaluate", "--report", str(store.root)]) == 0
    return store.root


def _damaged(results, tmp_path, damage):
    folder = tmp_path / "results"
    shutil.copytree(results, folder)
    damage(folder)
    return folder


RUN = "runs/paper_sim__pcvfe__s000"
REFUSED = {
    "runs.parquet garbled": (
        lambda f: (f / "runs.parquet").write_text("x"),
        "runs.parquet: not a readable Parquet table",
    ),
    "runs.parquet empty": (
        lambda f: (f / "runs.parquet").write_bytes(b""),
        "runs.parquet: not a readable",
    ),
    "runs.parquet of another table": (
        lambda f: pd.DataFrame({"a": [1]}).to_parquet(f / "runs.parquet"),
        "runs.parquet: not a results table of pcvfe evaluate (no column(s) run_id",
    ),
    "laps.parquet garbled": (
        lambda f: (f / "laps.parquet").write_text("x"),
        "laps.parquet: not a readable",
    ),
    "experiment.yaml garbled": (
        lambda f: (f / "experiment.yaml").write_text("[: :\n"),
        "experiment.yaml: not valid YAML",
    ),
    "experiment.yaml a list": (
        lambda f: (f / "experiment.yaml").write_text("- 1\n"),
        "experiment.yaml: not an experiment",
    ),
    "environment.json garbled": (
        lambda f: (f / "environment.json").write_text("{"),
        "environment.json: not valid JSON",
    ),
    "no runs.parquet": (lambda f: (f / "runs.parquet").unlink(), "no runs.parquet here"),
    "runs.parquet with no rows": (
        lambda f: pd.read_parquet(f / "runs.parquet").iloc[:0].to_parquet(f / "runs.parquet"),
        "runs.parquet: no runs recorded yet, nothing to report",
    ),
    "report.md is a folder": (
        lambda f: ((f / "report.md").unlink(), (f / "report.md").mkdir()),
        "report.md: it is a folder",
    ),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_a_damaged_results_file_is_named(results, tmp_path, capsys, case):
    damage, words = REFUSED[case]
    folder = _damaged(results, tmp_path, damage)
    assert main(["evaluate", "--report", str(folder)]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and err.count("\n") == 1


DEGRADED = {
    "a drive log missing": (
        lambda f: (f / RUN / "drive_log.parquet").unlink(),
        "paper_sim__pcvfe__s000 (missing)",
    ),
    "a drive log garbled": (
        lambda f: (f / RUN / "drive_log.parquet").write_text("x"),
        "paper_sim__pcvfe__s000 (",
    ),
    "a summary.json garbled": (lambda f: (f / RUN / "summary.json").write_text("{"), None),
    "a scenario.yaml garbled": (lambda f: (f / RUN / "scenario.yaml").write_text("[: :"), None),
    "runs/ gone": (lambda f: shutil.rmtree(f / "runs"), "(missing)"),
    "experiment.yaml gone": (
        lambda f: (f / "experiment.yaml").unlink(),
        "(experiment.yaml missing)",
    ),
}


@pytest.mark.parametrize("case", sorted(DEGRADED))
def test_a_damaged_run_is_drawn_around_and_said(results, tmp_path, capsys, case):
    damage, words = DEGRADED[case]
    folder = _damaged(results, tmp_path, damage)
    assert main(["evaluate", "--report", str(folder)]) == 0
    report = (folder / "report.md").read_text()
    assert "| pcvfe | 2 |" in report  # the runs table still carries every run
    if words is not None:
        assert words in report
    assert "## The experiment as run" in report and "## Versions" in report  # to its end
