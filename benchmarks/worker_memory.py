"""Memory of a worker that runs one simulation after another (``pcvfe evaluate``'s task).

Runs ``--runs`` short ``paper_sim`` runs (seeds 0, 1, ...) through
``pcvfe_drake.diagrams.evaluate_run.run_one`` in this one process, twice: with the run loop
as it is (``release_diagram`` frees each finished diagram) and with the release switched off
(what pydrake alone collects). Reports Python's traced memory (``tracemalloc``) and the resident
size after each run; the figure is the growth per run from the second run on (the first run
fills caches). Two processes are not needed: the variant without the release runs second, so
its leak cannot inflate the first.

Usage: python benchmarks/worker_memory.py [--quick] [--runs 6] [--duration 4]
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import tracemalloc

import psutil
import yaml

from pcvfe_drake.diagrams import run_simulation as run_module
from pcvfe_drake.diagrams.evaluate_run import run_one
from pcvfe_drake.diagrams.scenario_io import load_scenario


def series(runs: int, duration_s: float, label: str) -> dict:
    base = load_scenario("paper_sim")
    traced, rss = [], []
    for seed in range(runs):
        scenario = dataclasses.replace(base, seed=seed, laps=None, duration_s=duration_s)
        spec = {"run_id": f"{label}{seed}", "scenario": yaml.safe_load(scenario.to_yaml())}
        result = run_one(spec)
        if result["status"] != "done":
            raise RuntimeError(f"run {seed} failed: {result.get('error')}")
        del result
        gc.collect()
        traced.append(tracemalloc.get_traced_memory()[0] / 2**20)
        rss.append(psutil.Process().memory_info().rss / 2**20)
        print(f"{label} run {seed}: traced {traced[-1]:.1f} MB, rss {rss[-1]:.0f} MB", flush=True)
    per_run = (traced[-1] - traced[1]) / max(runs - 2, 1)
    return {"traced_mb": traced, "rss_mb": rss, "traced_growth_mb_per_run": per_run}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="4 runs of 1 s")
    parser.add_argument("--runs", type=int, default=6)
    parser.add_argument("--duration", type=float, default=4.0, help="simulated seconds per run")
    args = parser.parse_args()
    runs, duration = (4, 1.0) if args.quick else (max(args.runs, 3), args.duration)
    tracemalloc.start(1)
    released = series(runs, duration, "release")
    original = run_module.release_diagram
    run_module.release_diagram = lambda diagram: 0
    try:
        kept = series(runs, duration, "no_release")
    finally:
        run_module.release_diagram = original
    out = {
        "benchmark": "worker_memory",
        "runs": runs,
        "duration_s": duration,
        "with_release": released,
        "without_release": kept,
        "growth_mb_per_run_with_release": released["traced_growth_mb_per_run"],
        "growth_mb_per_run_without_release": kept["traced_growth_mb_per_run"],
    }
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
