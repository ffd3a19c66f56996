"""Per-run driving and friction metrics scored on the truth (no pydrake).

Every function reads a run log (``pcvfe_drake.runs.runlog`` columns) and scores the *true* state
where the log has it (the sim-only ``true_sx`` ... ``true_beta`` columns; the state columns are
then the measured state the estimator and controller saw); logs without truth columns (hardware,
or runs before sensing existed) are scored on their state columns. ``mu_true`` is the friction
under the car.

- :func:`truth_frame`: the log with its state columns replaced by the true state.
- :func:`friction_utilisation`: the acceleration demand ``sqrt(a_x^2 + a_y^2) / (mu g)``, with
  ``a_x = dv/dt`` and ``a_y = v psi_dot`` from the true state: time above 1 (the demand beyond
  the true limit), its fraction, the time-weighted mean (how much of the grip the driving
  uses), the 95th percentile and the maximum.
- :func:`mu_error_after_settling`: the time-weighted |mu_hat - mu_true| over the samples at
  least ``settle_s`` (10 s) after entering the current terrain (transition strips excluded):
  the steady-state error of any friction source, with or without contexts.
- :func:`transition_response`: per entry into a terrain, the time until mu_hat is first within
  ``tol`` (0.05) of that terrain's mu (null if never during the visit); with the context column,
  also the time until the visit's context was first reported (``context_id_s``) and, given the
  fitter's first-fit times, until that context had a fit (``first_fit_s``); with the lateral
  error, its largest magnitude over the visit.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from typing import Any

import numpy as np
import pandas as pd

from pcvfe_drake.runs.drivelog import TRUE_STATE_COLUMNS
from pcvfe_drake.vehicle.single_track import STATE_NAMES

G_MPS2 = 9.81
SETTLE_AFTER_ENTRY_S = 10.0
"""A terrain visit is scored for the steady-state mu error from this long after its entry [s]."""
TRANSITION_TOL = 0.05
"""The transition response ends when |mu_hat - mu_true| is first within this."""


def _weights(t: np.ndarray) -> np.ndarray:
    if t.size < 2:
        return np.ones_like(t)
    dt = np.diff(t)
    return np.append(dt, dt[-1])


def has_truth(log: pd.DataFrame) -> bool:
    """True when the log has a usable true state (every ``true_*`` column, some finite)."""
    cols = [c for c in TRUE_STATE_COLUMNS if c in log.columns]
    return len(cols) == len(TRUE_STATE_COLUMNS) and bool(
        np.isfinite(log[cols].to_numpy(float)).any()
    )


def truth_frame(log: pd.DataFrame) -> pd.DataFrame:
    """The log with the state columns holding the true state (a copy; unchanged without one)."""
    if not has_truth(log):
        return log
    out = log.copy()
    for name, true_name in zip(STATE_NAMES, TRUE_STATE_COLUMNS, strict=True):
        out[name] = log[true_name].to_numpy(float)
    return out


def _visits(terrain: np.ndarray, excluded: Collection[str]) -> list[tuple[int, int, str]]:
    """(first row, end row, name) of each run of equal terrain names not excluded."""
    out = []
    start = 0
    for i in range(1, len(terrain) + 1):
        if i == len(terrain) or terrain[i] != terrain[start]:
            name = str(terrain[start])
            if name and name not in excluded:
                out.append((start, i, name))
            start = i
    return out


def friction_utilisation(truth: pd.DataFrame, g: float = G_MPS2) -> dict[str, Any]:
    """Demand over the true friction limit (module docstring), from a :func:`truth_frame`."""
    t = truth["t"].to_numpy(float)
    v = truth["v"].to_numpy(float)
    r = truth["psi_dot"].to_numpy(float)
    mu = truth["mu_true"].to_numpy(float)
    if t.size < 3:
        return {
            "mean": None,
            "time_above_limit_s": None,
            "fraction_above_limit": None,
            "p95": None,
            "max": None,
        }
    a_x = np.gradient(v, t)
    demand = np.hypot(a_x, v * r) / (np.maximum(mu, 1e-6) * g)
    ok = np.isfinite(demand)
    w = _weights(t)
    above = ok & (demand > 1.0)
    total = float(np.sum(w[ok]))
    return {
        "mean": float(np.average(demand[ok], weights=w[ok])) if ok.any() else None,
        "time_above_limit_s": float(np.sum(w[above])),
        "fraction_above_limit": float(np.sum(w[above]) / total) if total > 0 else None,
        "p95": float(np.percentile(demand[ok], 95)) if ok.any() else None,
        "max": float(np.max(demand[ok])) if ok.any() else None,
    }


def mu_error_after_settling(
    log: pd.DataFrame, excluded: Collection[str] = (), settle_s: float = SETTLE_AFTER_ENTRY_S
) -> dict[str, Any]:
    """Time-weighted |mu_hat - mu_true| from ``settle_s`` after each terrain entry on."""
    t = log["t"].to_numpy(float)
    w = _weights(t)
    err = np.abs(log["mu_hat"].to_numpy(float) - log["mu_true"].to_numpy(float))
    terrain = log["terrain"].astype(str).to_numpy()
    scored = np.zeros(len(t), dtype=bool)
    for a, b, _ in _visits(terrain, set(excluded)):
        scored[a:b] = t[a:b] >= t[a] + settle_s
    scored &= np.isfinite(err)
    if not scored.any():
        return {"settle_s": settle_s, "mean": None, "max": None, "scored_time_s": 0.0}
    return {
        "settle_s": settle_s,
        "mean": float(np.average(err[scored], weights=w[scored])),
        "max": float(np.max(err[scored])),
        "scored_time_s": float(np.sum(w[scored])),
    }


def visit_context(ctx: np.ndarray) -> int | None:
    """The context of a visit: the id most often reported over its rows (noise left out)."""
    ids = ctx[ctx >= 0]
    if ids.size == 0:
        return None
    values, counts = np.unique(ids, return_counts=True)
    return int(values[np.argmax(counts)])


def transition_response(
    log: pd.DataFrame,
    excluded: Collection[str] = (),
    tol: float = TRANSITION_TOL,
    *,
    first_fit_s: Mapping[int, float] | None = None,
    lateral_error_m: np.ndarray | None = None,
) -> dict[str, Any]:
    """Per terrain entry (the run's start excluded): time until |mu_hat - mu_true| <= ``tol``.

    Each entry also has, where the log allows: ``context`` (the visit's context,
    :func:`visit_context` of its rows' ``context`` column) and ``context_id_s``, the time from
    the entry until that context was first reported (the new terrain's latency to an id: a
    re-clustering must name a terrain never seen before); ``first_fit_s``, the time from the
    entry until that context had its first fit (``first_fit_s``: {context id: sim time of its
    first fit [s]}; never before ``context_id_s``: the estimate reaches the controller with
    the id); ``max_abs_lateral_error_m`` over the visit (``lateral_error_m``: per row [m]).
    Times are None when it never happened during the visit.
    """
    t = log["t"].to_numpy(float)
    err = np.abs(log["mu_hat"].to_numpy(float) - log["mu_true"].to_numpy(float))
    terrain = log["terrain"].astype(str).to_numpy()
    ctx = log["context"].to_numpy(float) if "context" in log.columns else None
    entries = []
    for a, b, name in _visits(terrain, set(excluded)):
        if a == 0:
            continue
        within = np.flatnonzero(err[a:b] <= tol)
        latency = float(t[a + within[0]] - t[a]) if within.size else math.inf
        entry: dict[str, Any] = {
            "terrain": name,
            "t_enter_s": float(t[a]),
            "visit_s": float(t[b - 1] - t[a]),
            "response_s": latency if math.isfinite(latency) else None,
        }
        if ctx is not None:
            ids = np.where(np.isfinite(ctx[a:b]), ctx[a:b], -1).astype(int)
            k = visit_context(ids)
            entry["context"] = k
            named = None if k is None else float(t[a + np.flatnonzero(ids == k)[0]] - t[a])
            entry["context_id_s"] = named
            fit = None
            if named is not None and first_fit_s is not None:
                t_fit = first_fit_s.get(k)
                if t_fit is not None and math.isfinite(t_fit) and t_fit <= t[b - 1]:
                    fit = max(named, float(t_fit - t[a]))
            entry["first_fit_s"] = fit
        if lateral_error_m is not None:
            lat = np.abs(np.asarray(lateral_error_m, dtype=float)[a:b])
            entry["max_abs_lateral_error_m"] = (
                float(np.nanmax(lat)) if np.isfinite(lat).any() else None
            )
        entries.append(entry)
    done = [e["response_s"] for e in entries if e["response_s"] is not None]
    return {
        "tolerance": tol,
        "entries": entries,
        "median_s": float(np.median(done)) if done else None,
        "max_s": float(np.max(done)) if done else None,
        "never_within": sum(e["response_s"] is None for e in entries),
    }
