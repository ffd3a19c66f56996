"""`pcvfe evaluate` scores a run whose multi-body truth ended (a car braked into reverse) as a
catastrophic failure in its tables, not as a failed run with an error."""

import numpy as np
import pandas as pd

from pcvfe_drake.control.nmpc import NmpcController
from pcvfe_drake.diagrams.experiment_io import load_experiment, run_specs
from pcvfe_drake.evaluation.runner import open_client, run_sweep
from pcvfe_drake.evaluation.store import ResultStore

REVERSING = """
name: reversing
scenarios: [paper_sim_mb]
sources:
  - name: oracle
    overrides: {estimator: oracle, initial_speed_mps: 0.5}
seeds: 1
duration_s: 4.0
"""


def test_a_truth_singularity_is_a_row_of_the_failures_table(tmp_path, monkeypatch):
    real = NmpcController.step

    def full_brake(self, x, theta, memory):  # in-process cluster: the worker sees the patch
        _, memory, diagnostics = real(self, x, theta, memory)
        return np.array([0.0, -self.params.a_max]), memory, diagnostics

    monkeypatch.setattr(NmpcController, "step", full_brake)
    path = tmp_path / "reversing.yaml"
    path.write_text(REVERSING)
    exp, path = load_experiment(path)
    store = ResultStore(tmp_path / "out")
    store.start(exp.to_dict(), {"command": "test"})
    with open_client(1, processes=False) as client:
        stats = run_sweep(run_specs(exp, path), store, client, progress=False)
    assert (stats.done, stats.failed) == (1, 0)
    runs = pd.read_parquet(store.table_path("runs"))
    assert list(runs["status"]) == ["done"] and list(runs["error"]) == [""]
    assert runs["failures"].iloc[0] >= 1
    failures = pd.read_parquet(store.table_path("failures"))
    assert failures["kind"].iloc[-1] == "truth_singular"
    assert 0.0 < failures["t_s"].iloc[-1] < 2.0
