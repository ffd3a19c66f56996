"""Rows of the evaluation tables, made from one run's summary and run log (no pydrake).

- :func:`run_row`: one row per run (identity, status, timings, the metrics of :data:`METRICS`).
- :func:`lap_rows`: one row per lap started (start/end time, lap time when complete, mean speed,
  lateral error, failures in it).
- :func:`context_rows`: one row per discovered context (``summary["mu_estimates"]``).
- :func:`failure_rows`: one row per catastrophic failure (time, place, kind).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from pcvfe_drake.runs.summary import sample_weights


@dataclass(frozen=True)
class Metric:
    """A per-run number compared across sources."""

    column: str
    """Column of the runs table."""
    label: str
    unit: str
    better: str
    """``"higher"`` or ``"lower"``."""
    paths: tuple[tuple[str, ...], ...]
    """Where it is in summary.json (nested keys); the first path present wins."""


METRICS: tuple[Metric, ...] = (
    Metric("mean_speed_mps", "mean speed", "m/s", "higher", (("mean_speed_mps",),)),
    Metric("lap_time_s", "lap time", "s", "lower", (("lap_time_s",),)),
    Metric("failures", "catastrophic failures", "", "lower", (("catastrophic_failures",),)),
    Metric("lateral_error_rms_m", "lateral error RMS", "m", "lower", (("lateral_error_rms_m",),)),
    Metric("mu_error", "mu error (time-weighted)", "", "lower", (("mu_abs_error_time_weighted",),)),
    Metric(
        "mu_error_settled",
        "mu error after entry",
        "",
        "lower",
        (("mu_error_after_entry", "mean"), ("mu_error_after_settle", "worst_mean")),
    ),
    Metric(
        "transition_response_s",
        "transition response (median)",
        "s",
        "lower",
        (("transition_response", "median_s"), ("transition_response_s",)),
    ),
    Metric(
        "above_friction_limit",
        "time above the friction limit (fraction)",
        "",
        "lower",
        (("friction_utilisation", "fraction_above_limit"),),
    ),
)
"""The metrics of the report, in its column order. A metric a run's summary lacks is NaN."""


def _get(summary: Mapping[str, Any], paths: Sequence[Sequence[str]]) -> float:
    for path in paths:
        node: Any = summary
        for key in path:
            if not isinstance(node, Mapping) or key not in node:
                break
            node = node[key]
        else:
            try:
                return float(node) if node is not None else math.nan
            except (TypeError, ValueError):
                return math.nan
    return math.nan


def _number(x) -> float:
    return float(x) if x is not None else math.nan


def metric_values(summary: Mapping[str, Any]) -> dict[str, float]:
    """The :data:`METRICS` of one summary.json as ``{column: value}`` (NaN where missing)."""
    return {m.column: _get(summary, m.paths) for m in METRICS}


def run_row(spec: Mapping[str, Any], result: Mapping[str, Any]) -> dict[str, Any]:
    """The runs-table row of a finished (or failed) run."""
    summary = result.get("summary") or {}
    row: dict[str, Any] = {
        "run_id": spec["run_id"],
        "experiment": spec["experiment"],
        "scenario": spec["scenario_name"],
        "world": spec.get("world", ""),
        "source": spec["source"],
        "seed": int(spec["seed"]),
        "spec_hash": spec["spec_hash"],
        "status": result["status"],
        "error": result.get("error") or "",
        "worker": result.get("worker") or "",
        "finished_utc": result.get("finished_utc") or "",
        "task_wall_s": _number(result.get("task_wall_s")),
        "sim_wall_s": _number(summary.get("wall_time_s")),
        "sim_time_s": _number(summary.get("sim_time_s")),
        "laps_completed": _number(summary.get("laps_completed")),
        "peak_rss_mb": _number(result.get("peak_rss_mb")),
        "versions": result.get("versions") or "",
    }
    row.update(metric_values(summary) if summary else {m.column: math.nan for m in METRICS})
    return row


def lap_rows(log: pd.DataFrame, course, failure_times_s: Sequence[float] = ()) -> list[dict]:
    """One row per lap started along ``course`` (a ``pcvfe_drake.control.course.Course``).

    Columns: ``lap`` (0-based), ``t_start_s``, ``t_end_s`` (None while unfinished),
    ``complete``, ``lap_time_s``, ``mean_speed_mps`` (time-weighted), ``lateral_error_rms_m``,
    ``failures`` (failure events whose time falls in the lap).
    """
    t = log["t"].to_numpy(float)
    xy = log[["sx", "sy"]].to_numpy(float)
    ok = np.all(np.isfinite(xy), axis=1) & np.isfinite(t)
    if ok.sum() < 2:
        return []
    t, xy, v = t[ok], xy[ok], log["v"].to_numpy(float)[ok]
    proj = course.project(xy)
    travelled = course.unwrap_progress(np.asarray(proj.s, dtype=float))
    travelled = np.maximum.accumulate(travelled - travelled[0])
    lat = np.asarray(proj.lateral_error, dtype=float)
    w = sample_weights(t)
    n_laps = int(np.floor(travelled[-1] / course.length)) + 1
    failures = np.asarray(list(failure_times_s), dtype=float)
    rows = []
    for k in range(n_laps):
        lo, hi = k * course.length, (k + 1) * course.length
        t0 = float(np.interp(lo, travelled, t)) if k else float(t[0])
        complete = bool(travelled[-1] >= hi)
        t1 = float(np.interp(hi, travelled, t)) if complete else None
        sel = (travelled >= lo) & (travelled < hi)
        if not sel.any():
            continue
        end = t1 if t1 is not None else math.inf
        rows.append(
            {
                "lap": k,
                "t_start_s": t0,
                "t_end_s": t1,
                "complete": complete,
                "lap_time_s": (t1 - t0) if t1 is not None else None,
                "mean_speed_mps": float(np.average(v[sel], weights=w[sel])),
                "lateral_error_rms_m": float(np.sqrt(np.mean(lat[sel] ** 2))),
                "failures": int(np.count_nonzero((failures >= t0) & (failures < end))),
            }
        )
    return rows


def context_rows(summary: Mapping[str, Any]) -> list[dict]:
    """One row per context of ``summary["mu_estimates"]`` (id, estimate, truth, errors)."""
    keys = (
        "id",
        "fitted",
        "mu_hat",
        "handed_mu",
        "std",
        "samples",
        "majority_terrain",
        "true_mu",
        "abs_error",
        "abs_error_after_settle_mean",
        "abs_error_after_settle_max",
        "time_in_context_s",
        "covered_95",
    )
    return [{k: e.get(k) for k in keys} for e in summary.get("mu_estimates") or []]


MU_TOLERANCE = 0.05
"""|mu_hat - mu| a context must stay within after its first 20 s of driving to count as settled
(``abs_error_after_settle_max``, scored from ``runs.summary.SETTLE_TIME_S`` on)."""


def terrain_rows(contexts: pd.DataFrame, tolerance: float = MU_TOLERANCE) -> list[dict]:
    """Friction estimates per scenario, source and terrain, over the (context, run) pairs of
    ``contexts`` (the ``contexts`` table: one row per discovered context of every run).

    Per group: ``pairs`` (contexts whose majority terrain it is), ``scored`` (those driven long
    enough to be scored after their first 20 s), ``within`` (scored ones whose largest error
    after that stayed <= ``tolerance``), ``interval_known`` / ``covered`` (contexts whose run
    reported a 95 % interval, and how many held the truth; absent in results written before
    ``covered_95`` was stored), ``true_mu`` and the final ``mu_hat`` range over the pairs.
    Contexts without a majority terrain or a true mu are left out.
    """
    if contexts.empty or "majority_terrain" not in contexts:
        return []
    c = contexts[contexts["majority_terrain"].notna() & contexts["true_mu"].notna()]
    rows = []
    for (scenario, source, terrain), g in c.groupby(
        ["scenario", "source", "majority_terrain"], sort=True
    ):
        err = pd.to_numeric(g["abs_error_after_settle_max"], errors="coerce")
        scored = err.notna()
        cov = g["covered_95"] if "covered_95" in g else pd.Series(dtype=object)
        known = cov.notna() & cov.map(lambda x: isinstance(x, (bool, np.bool_)))
        mu_hat = pd.to_numeric(g["mu_hat"], errors="coerce")
        rows.append(
            {
                "scenario": scenario,
                "source": source,
                "terrain": terrain,
                "true_mu": float(g["true_mu"].iloc[0]),
                "pairs": len(g),
                "scored": int(scored.sum()),
                "within": int((err[scored] <= tolerance).sum()),
                "interval_known": int(known.sum()),
                "covered": int(cov[known].astype(bool).sum()),
                "mu_hat_min": float(mu_hat.min()) if mu_hat.notna().any() else math.nan,
                "mu_hat_max": float(mu_hat.max()) if mu_hat.notna().any() else math.nan,
            }
        )
    return rows


def failure_rows(summary: Mapping[str, Any]) -> list[dict]:
    """One row per catastrophic failure of the summary (t_s, sx_m, sy_m, kind), from its
    ``failures`` list (x_m, y_m, reason) or its ``failure_events`` list (sx_m, sy_m, kind)."""
    rows = []
    for e in summary.get("failures") or summary.get("failure_events") or []:
        rows.append(
            {
                "t_s": e.get("t_s"),
                "sx_m": e.get("x_m", e.get("sx_m")),
                "sy_m": e.get("y_m", e.get("sy_m")),
                "kind": e.get("reason", e.get("kind")),
            }
        )
    return rows
