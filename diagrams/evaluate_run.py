"""One run of an experiment, as a task for a Dask worker (``pcvfe evaluate``).

:func:`run_one` takes a run spec as a plain mapping (``RunSpec.to_dict()``: the complete scenario
included, so a worker on another host needs only this package installed, no shared files),
simulates it without Meshcat, and returns everything the client stores: the summary, the rows of
the lap / context / failure tables, and the drive log as Parquet bytes. Any exception of the run is
caught and returned as ``status: "failed"`` with the error and traceback, so one bad run never
stops a sweep.
"""

from __future__ import annotations

import io
import platform
import resource
import sys
import time
import traceback
from datetime import UTC, datetime
from importlib import metadata
from typing import Any

import yaml

VERSIONED = ("pcvfe-drake", "drake", "numpy", "scipy", "osqp", "pandas", "dask", "distributed")
"""Packages whose versions each run records (the worker's, which a cluster may mix)."""


def package_versions() -> dict[str, str]:
    """Installed versions of :data:`VERSIONED` and Python (``"?"`` when not installed)."""
    out = {"python": platform.python_version()}
    for name in VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "?"
    return out


def _peak_rss_mb() -> float:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


def _current_rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / (1024.0 * 1024.0)


def run_one(spec: dict[str, Any]) -> dict[str, Any]:
    """Simulate one run spec; returns the result mapping (never raises for a failing run)."""
    t0 = time.perf_counter()
    rss_start = _current_rss_mb()
    result: dict[str, Any] = {
        "run_id": spec["run_id"],
        "worker": platform.node(),
        "versions": ", ".join(f"{k} {v}" for k, v in package_versions().items()),
    }
    try:
        result.update(_simulate(spec))
        result["status"] = "done"
    except Exception as exc:  # noqa: BLE001 - every failure of a run is recorded, the sweep goes on
        result.update(
            status="failed",
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(),
        )
    result["task_wall_s"] = time.perf_counter() - t0
    result["rss_start_mb"] = rss_start
    result["peak_rss_mb"] = _peak_rss_mb()
    result["finished_utc"] = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    return result


def _simulate(spec: dict[str, Any]) -> dict[str, Any]:
    from pcvfe_drake.diagrams.run_simulation import run_simulation
    from pcvfe_drake.diagrams.scenario_io import scenario_from_yaml_text
    from pcvfe_drake.diagrams.world_io import scenario_course
    from pcvfe_drake.evaluation.tables import context_rows, failure_rows, lap_rows

    scenario = scenario_from_yaml_text(
        yaml.safe_dump(spec["scenario"], sort_keys=False), source=f"run {spec['run_id']}"
    )
    sim = run_simulation(scenario, None, progress=False, write_outputs=False)
    summary = sim.summary
    failures = failure_rows(summary)
    laps = lap_rows(sim.log, scenario_course(scenario), [f["t_s"] for f in failures])
    buffer = io.BytesIO()
    sim.log.to_parquet(buffer, index=False)
    return {
        "summary": summary,
        "laps": laps,
        "contexts": context_rows(summary),
        "failures": failures,
        "drive_log_parquet": buffer.getvalue(),
        "error": summary.get("error") or "",
    }
