"""Throughput of `pcvfe evaluate` with 1 and 2 Dask workers, and the runner's own overhead per run.

The same grid (``paper_sim``, PC-VFE, K seeds of D simulated seconds each) runs twice in this
process through the real runner (``run_sweep``: Dask LocalCluster of worker processes, results
stored as they arrive): once on 1 worker, once on 2. Each cluster is warmed first (one short run
pinned to every worker, so imports and caches are not timed). Reported:

- ``runs_per_hour_1`` / ``runs_per_hour_2`` and their ratio (target: 2 workers >= 1.7x one; the
  machine's other load shares the same cores, see ``load_average``);
- ``runner_overhead_fraction``: per run, the sweep's wall time on 1 worker minus the time the task
  spent on its worker (dispatch, transfer of the result, the tables written on the client),
  divided by the run's simulation time (``AdvanceTo``, ``sim_wall_s``) (target < 5 %);
- ``task_setup_fraction``: the task's own time outside ``AdvanceTo`` (diagram build, summary,
  lap rows, Parquet log) over the simulation time: a cost of the run, not of the runner;
- ``peak_rss_mb``: the largest peak resident memory of a worker process after its runs, and
  ``idle_worker_rss_mb`` that of a warmed worker before them.

Usage: python benchmarks/evaluate_scaling.py [--quick] [--runs K] [--duration S]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from pcvfe_drake.diagrams.evaluate_run import run_one
from pcvfe_drake.diagrams.experiment_io import run_specs
from pcvfe_drake.evaluation.experiment import Experiment, Source
from pcvfe_drake.evaluation.runner import open_client, run_sweep
from pcvfe_drake.evaluation.store import ResultStore


def _rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def sweep(n_workers: int, specs, warm_spec, out: Path) -> dict:
    """Run ``specs`` on a fresh local cluster of ``n_workers``; returns timings."""
    store = ResultStore(out)
    store.start({"name": "bench"}, {})
    with open_client(n_workers) as client:
        client.wait_for_workers(n_workers)
        workers = list(client.scheduler_info()["workers"])
        warm = [
            client.submit(run_one, {**warm_spec, "run_id": f"warm-{i}"}, workers=[w], pure=False)
            for i, w in enumerate(workers)
        ]
        for f in warm:
            assert f.result()["status"] == "done", f.result().get("error")
        idle = client.run(_rss_mb)
        t0 = time.perf_counter()
        stats = run_sweep(specs, store, client, progress=False)
        wall = time.perf_counter() - t0
    runs = store.table("runs")
    assert stats.done == len(specs), stats.failures
    return {
        "workers": n_workers,
        "runs": len(specs),
        "wall_s": wall,
        "runs_per_hour": len(specs) / wall * 3600.0,
        "task_wall_s": runs["task_wall_s"].to_numpy(float),
        "sim_wall_s": runs["sim_wall_s"].to_numpy(float),
        "record_s": np.asarray(stats.record_s),
        "peak_rss_mb": float(runs["peak_rss_mb"].max()),
        "idle_worker_rss_mb": float(max(idle.values())),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="4 runs of 10 s")
    parser.add_argument("--runs", type=int, default=None, help="runs per sweep (default 6)")
    parser.add_argument("--duration", type=float, default=None, help="simulated s (default 60)")
    args = parser.parse_args()
    k = args.runs or (4 if args.quick else 6)
    duration = args.duration or (10.0 if args.quick else 60.0)
    exp = Experiment(name="bench", sources=[Source(name="pcvfe")], seeds=k, duration_s=duration)
    specs = run_specs(exp, Path("bench.yaml"))
    warm = run_specs(
        Experiment(name="bench", sources=[Source(name="pcvfe")], seeds=1, duration_s=1.0),
        Path("bench.yaml"),
    )[0].to_dict()
    print(f"evaluate_scaling: {k} runs of {duration:.0f} s simulated, 1 then 2 workers")
    with tempfile.TemporaryDirectory() as tmp:
        one = sweep(1, specs, warm, Path(tmp) / "one")
        print(f"  1 worker:  {one['wall_s']:.1f} s, {one['runs_per_hour']:.0f} runs/h")
        two = sweep(2, specs, warm, Path(tmp) / "two")
        print(f"  2 workers: {two['wall_s']:.1f} s, {two['runs_per_hour']:.0f} runs/h")
    sim = float(np.mean(one["sim_wall_s"]))
    task = float(np.mean(one["task_wall_s"]))
    overhead = one["wall_s"] / k - task
    result = {
        "benchmark": "evaluate_scaling",
        "runs": k,
        "duration_s": duration,
        "runs_per_hour_1": one["runs_per_hour"],
        "runs_per_hour_2": two["runs_per_hour"],
        "speedup_2_workers_ratio": two["runs_per_hour"] / one["runs_per_hour"],
        "target_speedup": 1.7,
        "runner_overhead_per_run_s": overhead,
        "runner_overhead_fraction": overhead / sim,
        "target_overhead_fraction": 0.05,
        "store_per_run_s": float(np.mean(one["record_s"])),
        "sim_wall_per_run_s": sim,
        "task_wall_per_run_s": task,
        "task_setup_fraction": (task - sim) / sim,
        "sim_wall_per_run_s_2_workers": float(np.mean(two["sim_wall_s"])),
        "peak_rss_mb": max(one["peak_rss_mb"], two["peak_rss_mb"]),
        "idle_worker_rss_mb": max(one["idle_worker_rss_mb"], two["idle_worker_rss_mb"]),
        "cpus": os.cpu_count(),
        "load_average": list(os.getloadavg()),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
