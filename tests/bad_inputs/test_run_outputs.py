"""A run's outputs are always written: a run that only saw a transition strip is scored, and a
failure of the scoring itself (a bug) still leaves summary.json, reported as an internal error."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from pcvfe_drake.contexts import metrics
from pcvfe_drake.diagrams.world_io import scenario_world
from pcvfe_drake.runs import run_folder
from pcvfe_drake.runs.run_folder import RunFolder, RunRecord, write_run_outputs
from pcvfe_drake.runs.scenario import Scenario


def _strip_log(n: int = 8) -> pd.DataFrame:
    """A short drive whose every row is on the transition strip (gravel)."""
    t = 0.05 * np.arange(n)
    zeros = np.zeros(n)
    return pd.DataFrame(
        {
            "t": t,
            "sx": 3.0 * t,
            "sy": zeros,
            "delta": zeros,
            "v": np.full(n, 3.0),
            "psi": zeros,
            "psi_dot": zeros,
            "beta": zeros,
            "steer_rate": zeros,
            "accel": zeros,
            "terrain": ["gravel"] * n,
            "terrain_index": np.full(n, 4),
            "mu_true": np.full(n, 0.6),
            "context": np.full(n, -1),
            "mu_hat": np.full(n, 1.0),
            "final_context": np.full(n, -1),
        }
    )


def _record(log: pd.DataFrame) -> RunRecord:
    scenario = Scenario()
    world = scenario_world(scenario)
    return RunRecord(
        scenario=scenario,
        log=log,
        course=world.course,
        terrain_map=world.terrain_map,
        estimate_table=[],
        wall_time_s=1.0,
        cpu_time_s=1.0,
        nmpc_updates=0,
        nmpc_fallbacks=0,
    )


def test_no_included_sample_has_no_visit():
    labels = np.array(["gravel"] * 5, dtype=object)
    assert metrics.terrain_visits(labels, np.zeros(5, bool)) == []
    m = metrics.context_metrics(
        np.arange(5.0), labels, -np.ones(5, int), excluded_labels=["gravel"]
    )
    assert m.n_included == 0 and m.n_revisits == 0 and np.isnan(m.ari)


def test_a_run_that_only_sees_a_transition_strip_is_summarized(tmp_path):
    folder = RunFolder(tmp_path / "run")
    folder.root.mkdir()
    result = write_run_outputs(_record(_strip_log()), folder)
    assert not result.internal_errors
    summary = json.loads(folder.summary.read_text())
    assert summary["log_rows"] == 8
    assert summary["true_terrains_visited"] == []
    assert summary["contexts_discovered"] == 0
    assert summary["ari"] is None


def test_a_scoring_bug_still_writes_the_summary_and_says_so(tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise ValueError("planted scoring bug")

    monkeypatch.setattr(run_folder, "summarize_run", broken)
    folder = RunFolder(tmp_path / "run")
    folder.root.mkdir()
    _strip_log().to_csv(folder.drive_log, index=False)
    result = write_run_outputs(_record(_strip_log()), folder)
    summary = json.loads(folder.summary.read_text())
    assert summary["scored"] is False and summary["log_rows"] == 8
    assert summary["sim_time_s"] == pytest.approx(0.35)
    assert summary["internal_errors"][0]["stage"] == "summary"
    assert "planted scoring bug" in summary["internal_errors"][0]["message"]
    assert "Traceback" in folder.internal_error.read_text()
    report = run_folder.internal_error_report(result, folder)
    assert "internal error while writing the summary (a bug, not your input)" in report
    assert "drive_log.csv" in report and "summary.json without scores" in report


def test_a_short_run_that_starts_on_the_strip_writes_its_summary(tmp_path, capsys):
    """The issue's reproduction: 0.3 s from a start on the slalom's gravel strip (128 m along
    the course in the paper layout)."""
    from pcvfe_drake.cli import main

    layer = tmp_path / "strip.yaml"
    layer.write_text("start_s_m: 128.0\n")
    out = tmp_path / "run"
    argv = ["simulate", "--with", str(layer), "--duration", "0.3", "--no-meshcat", "--no-progress"]
    assert main([*argv, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["true_terrains_visited"] == [] and summary["log_rows"] == 6
    assert "internal_errors" not in summary and (out / "figures").is_dir()
