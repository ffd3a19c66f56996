"""The summary of a closed-loop PC-VFE run, computed from its run log (plain arrays, no pydrake).

The run log is the drive log of the run (``pcvfe_drake.runs.drivelog`` format) with the run's extra
columns: ``terrain`` (true terrain name), ``mu_true``, ``context`` (reported context id, -1 =
noise), ``mu_hat`` (the friction the controller was given), and optionally ``C_Sf_hat``,
``C_Sr_hat``, feature columns ``f_00``... and ``image``. :func:`summarize_run` turns it into the
dict written as ``summary.json``:

- ``sim_time_s``, ``wall_time_s``, ``realtime_factor`` (simulated / wall time).
- ``laps_completed``, ``lap_time_s`` (time of the first full lap, null if none), from the
  projection of the driven path onto the course; ``mean_speed_mps``.
- ``catastrophic_failures``: number of failure events (``pcvfe_drake.control.failure``: left
  the course by more than its half width, spinning with |beta| > 30 deg or a course-angle error
  > 60 deg, a non-finite state, or a truth that could no longer be integrated), ``failure_events`` (each with its time ``t_s``, place
  ``sx_m``, ``sy_m``, ``s_m`` (along the course), ``kind`` and ``detail``),
  ``max_abs_lateral_error_m``, ``lateral_error_rms_m``.
- Scored on the truth: when the log has the sim-only ``true_*`` state columns, laps, speed,
  tracking and failures use the true state (``drive_metrics.truth_frame``);
  ``friction_utilisation``, ``mu_error_after_entry`` and ``transition_response`` are
  described in ``pcvfe_drake.runs.drive_metrics``.
- Context discovery (``pcvfe_drake.contexts.metrics``; transition-strip terrains excluded): ``ari``,
  ``contexts_discovered``, ``true_terrains_visited``, ``noise_fraction``,
  ``reidentification_latency_s`` (one entry per re-entry of a terrain that already had an id),
  ``new_terrain_latency_s`` (per terrain, time to its first id).
- ``final_clustering`` (when the log has a ``final_context`` column: every logged frame labelled
  by the clustering as it stands at the end of the run, the paper's Fig. 4): its ``ari``,
  ``noise_fraction`` and number of ``contexts``. ``ari`` above is the online one: the ids as
  reported during the run, noise while a new terrain waits for its first re-clustering included.
- Friction: ``mu_estimates`` (per context: id, mu_hat, std, samples, majority true terrain, its
  true mu, abs error, and the time-weighted mean and the max abs error once the context has been
  in use for 20 s of driving, the time of its first fit and how long after the first entry into
  its terrain that came, whether the context was ever ``fitted`` and the ``handed_mu``, see
  :func:`mu_estimates`), ``mu_error_after_settle`` (the worst
  context's of those, and which contexts never reached 20 s), ``mu_abs_error_time_weighted``
  (|mu_hat - mu_true| over the whole run, weighted by time, the prior used while a terrain is
  still noise included).

Non-finite numbers (a re-identification that never happened: infinite latency) are written as
null in JSON, with the count of such cases beside them.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from pcvfe_drake.contexts import metrics
from pcvfe_drake.control import failure
from pcvfe_drake.estimation.estimate_table import Z95
from pcvfe_drake.json_numbers import finite_or_none
from pcvfe_drake.runs import drive_metrics

SETTLE_TIME_S = 20.0
"""A context's friction error is scored once it has this much driving in it (issue 7)."""

REQUIRED = ("t", "sx", "sy", "v", "psi", "beta", "terrain", "mu_true", "context", "mu_hat")


def _delays(value) -> dict | None:
    """``{p50, p99, samples}`` [s] of a table entry's sample-to-estimate waits (None: none)."""
    if not value or len(value) != 3 or not value[2]:
        return None
    return {"p50": float(value[0]), "p99": float(value[1]), "samples": int(value[2])}


def sample_weights(t_s: np.ndarray) -> np.ndarray:
    """Time each sample stands for [s]: the step to the next sample (the last repeats the one
    before), i.e. a zero-order hold of the logged values."""
    t = np.asarray(t_s, dtype=float)
    if t.size < 2:
        return np.ones_like(t)
    dt = np.diff(t)
    return np.append(dt, dt[-1])


def lateral_error_rows(log: pd.DataFrame, course) -> np.ndarray | None:
    """Signed lateral error [m] of every row's position against ``course`` (NaN where the state
    is not finite; None without a course)."""
    if course is None:
        return None
    xy = log[["sx", "sy"]].to_numpy(float)
    psi = log["psi"].to_numpy(float)
    finite = np.all(np.isfinite(xy), axis=1) & np.isfinite(psi)
    lat = np.full(len(log), np.nan)
    if finite.any():
        lat[finite] = course.project(xy[finite], heading=psi[finite]).lateral_error
    return lat


def course_tracking(
    log: pd.DataFrame, course, ending_failure: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Lap count, lap time and catastrophic failures of the driven path against ``course``.

    ``course`` is a ``pcvfe_drake.control.course.Course`` (or None: lap and tracking entries are
    None, and only non-finite states count as failures). Failures follow the project's one
    definition (``pcvfe_drake.control.failure``); ``failure_events`` lists each event with its
    time, place and reason. ``ending_failure``: the event that ended the run where no logged
    state shows it (a ``truth_singular`` event, ``FailureEvent.to_dict()``), counted last; when
    the last logged row had already failed, it is that failure's end (its detail added to the
    event's), not a second failure.
    """
    t = log["t"].to_numpy(float)
    xy = log[["sx", "sy"]].to_numpy(float)
    finite = np.all(np.isfinite(log[["sx", "sy", "v", "psi", "beta"]].to_numpy(float)), axis=1)
    beta = log["beta"].to_numpy(float)
    out: dict[str, Any] = {
        "laps_completed": None,
        "lap_time_s": None,
        "max_abs_lateral_error_m": None,
        "lateral_error_rms_m": None,
        "course_half_width_m": None,
    }
    lat = np.zeros(len(t))
    course_angle = np.zeros(len(t))
    s_along = np.full(len(t), np.nan)
    half_width = math.inf
    if course is not None and np.any(finite):
        proj = course.project(xy[finite], heading=log["psi"].to_numpy(float)[finite])
        lat = np.full(len(t), np.nan)
        lat[finite] = proj.lateral_error
        course_angle[finite] = proj.heading_error + beta[finite]
        s_along[finite] = proj.s
        half_width = course.half_width
        progress = course.unwrap_progress(np.asarray(proj.s))
        travelled = progress - progress[0]
        laps = int(np.floor(travelled[-1] / course.length + 1e-9))
        lap_time = None
        if laps >= 1:
            k = int(np.argmax(travelled >= course.length))
            tf = t[finite]
            if k > 0:
                frac = (course.length - travelled[k - 1]) / (travelled[k] - travelled[k - 1])
                lap_time = float(tf[k - 1] + frac * (tf[k] - tf[k - 1]) - tf[0])
            else:
                lap_time = float(tf[k] - tf[0])
        out.update(
            laps_completed=laps,
            lap_time_s=lap_time,
            laps_fraction=float(travelled[-1] / course.length),
            max_abs_lateral_error_m=float(np.nanmax(np.abs(lat))),
            lateral_error_rms_m=float(np.sqrt(np.nanmean(lat**2))),
            course_half_width_m=float(course.half_width),
        )
    kinds = failure.failure_kinds(half_width, lat, course_angle, beta, finite)
    events = failure.failure_events(t, xy, s_along, half_width, lat, course_angle, beta, finite)
    out["failure_events"] = [e.to_dict() for e in events]
    if ending_failure is not None:
        if len(kinds) and kinds[-1] != "" and out["failure_events"]:
            # The car had already failed at the last logged row (it left the course, then
            # spun out of the model before the next row): one failure, its end named too.
            last = out["failure_events"][-1]
            last["detail"] = f"{last['detail']}; then {ending_failure['detail']}"
        else:
            out["failure_events"].append(dict(ending_failure))
    out["catastrophic_failures"] = len(out["failure_events"])
    out["failure_time_s"] = float(np.sum(sample_weights(t)[kinds != ""]))
    return out


def mu_estimates(
    log: pd.DataFrame,
    terrain_mu: Mapping[str, float],
    *,
    excluded_terrains: Collection[str] = (),
    estimate_table: Sequence[Mapping[str, Any]] | None = None,
    settle_time_s: float = SETTLE_TIME_S,
) -> list[dict[str, Any]]:
    """Per discovered context: the friction estimate against the true mu of its majority terrain.

    ``estimate_table``: the fitter's final per-context table (dicts with ``id``, ``mu``,
    ``mu_std``, ``samples``, optionally ``status`` and ``first_fit_s``, the sim time of its first
    successful fit); ``first_fit_after_entry_s`` is that time minus the first time the car was
    on the majority terrain (how long a new terrain waited for an estimate of its own). Where a
    context is missing from the table, the last ``mu_hat`` logged while
    the context was current is used and ``std`` is None. A context the table lists without a
    fit (:func:`entry_fitted`) has ``fitted`` False and no ``mu_hat``, ``std``, ``abs_error`` or
    interval: its table mu is the prior (``prior_mu``), which no data produced and which the
    car may never have been handed. ``handed_mu`` is what the controller was given at the
    context's last sample (the log's ``mu_hat``: a fit, a probe level or the unknown-context
    value).

    The error "after its first 20 s" (issue 7's target, ``settle_time_s``): the time-weighted
    mean (``abs_error_after_settle_mean``) and the largest (``abs_error_after_settle_max``)
    |mu_hat - mu_true| over the samples reported as the context, on its majority terrain, from
    the moment the context has been reported for ``settle_time_s`` seconds of driving (the
    seconds the context was in use, summed over its visits: not the time since its first id,
    which would also count driving on other terrains while the context gathered no data).
    ``mu_hat`` is the estimate the controller was given at each sample (the fitter's output then),
    so the score covers the whole rest of the run, not just the final estimate; ``scored_time_s``
    is how much driving was scored. None when the context never reached ``settle_time_s``.
    ``covered_95``: whether the final estimate's 95 % interval holds the truth; the interval
    (``interval_95``, [low, high], None: unbounded) is the table's ``mu_interval_95`` (``mu +-
    1.96 std`` where the data came near the limit, ``[mu_lower_bound, inf)`` where they never
    did; ``ContextEstimate.mu_interval_95``), else ``mu_hat +- 1.96 std``.
    Identifiability (from the table, ``ContextEstimate``): ``mu_lower_bound`` (the friction the
    data used), ``near_limit``, ``identifiable``, ``untrusted`` (why the fit-quality checks
    distrust the fit), ``model_params`` of an effect model, and ``fits`` (the successful fits so
    far: the first and every refit; shows whether refits ran, e.g. beside the LCM loop).
    """
    t = log["t"].to_numpy(float)
    w = sample_weights(t)
    ctx = log["context"].to_numpy(int)
    terrain = log["terrain"].astype(str).to_numpy()
    mu_hat = log["mu_hat"].to_numpy(float)
    table = {int(r["id"]): r for r in (estimate_table or [])}
    excluded = set(excluded_terrains)
    out = []
    for k in sorted(int(c) for c in np.unique(ctx) if c >= 0):
        rows = np.flatnonzero(ctx == k)
        names = [n for n in terrain[rows] if n not in excluded and n]
        majority = max(set(names), key=names.count) if names else None
        true_mu = float(terrain_mu[majority]) if majority in terrain_mu else None
        entry = table.get(k)
        interval = None
        handed = float(mu_hat[rows[-1]])
        if entry is not None and not entry_fitted(entry):
            # No fit: the table's mu is the prior, not an estimate; the car was handed the
            # unknown-context value (logged as mu_hat), reported beside it.
            est = std = None
            samples = int(entry.get("samples", 0))
            status = entry.get("status")
            first_fit = None
            ident = {"prior_mu": float(entry["mu"])}
        elif entry is not None:
            est = float(entry["mu"])
            std = finite_or_none(entry.get("mu_std", math.nan))
            interval = entry.get("mu_interval_95")
            samples = int(entry.get("samples", 0))
            status = entry.get("status")
            first_fit = finite_or_none(entry.get("first_fit_s", math.nan))
            ident = {
                "mu_lower_bound": finite_or_none(entry.get("mu_lower_bound", math.nan)),
                "near_limit": entry.get("near_limit"),
                "identifiable": entry.get("identifiable"),
                "below_used": entry.get("below_used"),
                "untrusted": entry.get("untrusted"),
                "probe": entry.get("probe"),
                "handing": entry.get("handing"),
                "model_params": entry.get("model_params") or None,
                "sample_to_estimate_s": _delays(entry.get("sample_to_estimate_s")),
                "sample_to_refit_s": _delays(entry.get("sample_to_refit_s")),
                "fits": entry.get("fits"),
            }
        else:
            est = handed
            std = None
            samples = 0
            status = None
            first_fit = None
            ident = {}
        # Scored samples: reported as this context, on its majority terrain, once the context
        # has been reported for settle_time_s of driving (counted over every sample reported
        # as it, its first visit's and later ones alike).
        in_context_before = np.cumsum(w[rows]) - w[rows]
        settled = rows[(in_context_before >= settle_time_s) & (terrain[rows] == majority)]
        if interval is None or any(v is None or math.isnan(v) for v in interval):
            interval = (est - Z95 * std, est + Z95 * std) if std is not None else None
        if est is None:
            interval = None
        err_after = err_after_max = None
        if true_mu is not None and settled.size:
            err = np.abs(mu_hat[settled] - true_mu)
            err_after = float(np.average(err, weights=w[settled]))
            err_after_max = float(np.max(err))
        out.append(
            {
                "id": k,
                "fitted": est is not None,
                "mu_hat": est,
                "handed_mu": handed,
                "std": std,
                "samples": samples,
                "fit_status": status,
                "first_fit_s": first_fit,
                "first_fit_after_entry_s": (
                    None
                    if first_fit is None or majority is None
                    else first_fit - float(t[np.flatnonzero(terrain == majority)[0]])
                ),
                "time_in_context_s": float(np.sum(w[rows])),
                "majority_terrain": majority,
                "majority_share": (names.count(majority) / len(rows)) if majority else 0.0,
                "true_mu": true_mu,
                "abs_error": (
                    abs(est - true_mu) if true_mu is not None and est is not None else None
                ),
                "abs_error_after_settle_mean": err_after,
                "abs_error_after_settle_max": err_after_max,
                "scored_time_s": float(np.sum(w[settled])) if err_after is not None else 0.0,
                "interval_95": (
                    None if interval is None else [finite_or_none(v) for v in interval]
                ),
                "covered_95": (
                    bool(interval[0] <= true_mu <= interval[1])
                    if true_mu is not None and interval is not None
                    else None
                ),
                **ident,
            }
        )
    return out


NO_FIT_STATUSES = ("prior", "too_little_data")
"""Estimate-table statuses of a context that never had a successful fit (its mu is the prior)."""


def entry_fitted(entry: Mapping[str, Any]) -> bool:
    """Whether an estimate-table entry holds a fit (its ``mu`` an estimate, not the prior): not
    a no-fit status, and not a first refit that diverged (no ``first_fit_s``). An entry without
    a status (a table from elsewhere) counts as fitted."""
    status = entry.get("status")
    if status in NO_FIT_STATUSES:
        return False
    if status == "diverged":
        return finite_or_none(entry.get("first_fit_s", math.nan)) is not None
    return True


NO_TRUTH_NOTE = (
    "no ground truth on this station (hardware or a replayed real drive): ARI, terrain "
    "latencies and friction errors are not scored; contexts, estimates and tracking are"
)


def summarize_run(
    log: pd.DataFrame,
    *,
    scenario: str,
    wall_time_s: float,
    terrain_mu: Mapping[str, float],
    excluded_terrains: Collection[str] = (),
    course=None,
    estimate_table: Sequence[Mapping[str, Any]] | None = None,
    interrupted: bool = False,
    ending_failure: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The run's summary dict (see the module docstring); JSON-ready (no NaN/inf).
    ``ending_failure``: see :func:`course_tracking`."""
    missing = [c for c in REQUIRED if c not in log.columns]
    if missing:
        raise ValueError(f"run log lacks column(s) {missing}; it has {list(log.columns)}")
    if len(log) == 0:
        raise ValueError("run log is empty: nothing was logged")
    truth = drive_metrics.truth_frame(log)
    t = log["t"].to_numpy(float)
    w = sample_weights(t)
    sim_time = float(t[-1] - t[0] + (w[-1] if len(t) > 1 else 0.0))
    wall = float(wall_time_s)
    excluded = tuple(excluded_terrains) + metrics.DEFAULT_EXCLUDED
    terrain = log["terrain"].fillna("").astype(str).to_numpy()
    ctx = log["context"].to_numpy(int)
    mu_true = log["mu_true"].to_numpy(float)
    has_truth = bool(np.any(np.isfinite(mu_true)) or np.any(terrain != ""))
    if has_truth:
        m = metrics.context_metrics(t, terrain, ctx, excluded_labels=excluded)
        reid = metrics.reidentification_latencies(t, terrain, ctx, excluded_labels=excluded)
    else:
        m, reid = None, []
    visited = sorted({n for n in terrain if n and n not in set(excluded_terrains)})
    mu_hat = log["mu_hat"].to_numpy(float)
    ok = np.isfinite(mu_true) & np.isfinite(mu_hat)
    mu_err = float(np.average(np.abs(mu_hat - mu_true)[ok], weights=w[ok])) if ok.any() else None
    speed = truth["v"].to_numpy(float)
    fin = np.isfinite(speed)
    summary: dict[str, Any] = {
        "scenario": scenario,
        "interrupted": bool(interrupted),
        "sim_time_s": sim_time,
        "wall_time_s": wall,
        "realtime_factor": sim_time / wall if wall > 0 else None,
        "log_rows": len(log),
        "mean_speed_mps": float(np.average(speed[fin], weights=w[fin])) if fin.any() else None,
        "ground_truth": has_truth,
    }
    if not has_truth:
        summary["ground_truth_note"] = NO_TRUTH_NOTE
    summary["scored_on_truth"] = drive_metrics.has_truth(log)
    summary.update(course_tracking(truth, course, ending_failure))
    summary["friction_utilisation"] = drive_metrics.friction_utilisation(truth)
    summary["mu_error_after_entry"] = drive_metrics.mu_error_after_settling(log, excluded_terrains)
    first_fit = {
        int(r["id"]): float(r["first_fit_s"])
        for r in (estimate_table or [])
        if finite_or_none(r.get("first_fit_s", math.nan)) is not None
    }
    summary["transition_response"] = drive_metrics.transition_response(
        log,
        excluded_terrains,
        first_fit_s=first_fit,
        lateral_error_m=lateral_error_rows(truth, course),
    )
    summary["transition_response_s"] = summary["transition_response"]["median_s"]
    lat = [r[2] for r in reid]
    summary.update(
        {
            "contexts_discovered": (
                int(m.n_contexts) if m is not None else len({int(c) for c in ctx if c >= 0})
            ),
            "true_terrains_visited": visited,
            "excluded_terrains": sorted(set(excluded_terrains)),
            "ari": finite_or_none(m.ari) if m is not None else None,
            "noise_fraction": (
                finite_or_none(m.noise_fraction) if m is not None else float(np.mean(ctx < 0))
            ),
            "reidentification_latency_s": [
                {"terrain": str(lab), "t_enter_s": t0, "latency_s": finite_or_none(x)}
                for lab, t0, x in reid
            ],
            "reidentification_latency_median_s": finite_or_none(
                float(np.median(lat)) if lat else math.nan
            ),
            "reidentifications_missed": int(sum(not math.isfinite(x) for x in lat)),
            "new_terrain_latency_s": (
                {k: finite_or_none(v) for k, v in sorted(m.first_id_time_s.items())}
                if m is not None
                else {}
            ),
            "mu_estimates": mu_estimates(
                log,
                terrain_mu,
                excluded_terrains=excluded_terrains,
                estimate_table=estimate_table,
            ),
            "mu_abs_error_time_weighted": mu_err,
        }
    )
    scored = [e for e in summary["mu_estimates"] if e["abs_error_after_settle_mean"] is not None]
    summary["mu_error_after_settle"] = {
        "settle_time_s": SETTLE_TIME_S,
        "contexts_scored": len(scored),
        "contexts_unscored": [
            e["id"] for e in summary["mu_estimates"] if e["abs_error_after_settle_mean"] is None
        ],
        "worst_mean": max((e["abs_error_after_settle_mean"] for e in scored), default=None),
        "worst_max": max((e["abs_error_after_settle_max"] for e in scored), default=None),
    }
    if "final_context" in log.columns:
        final = log["final_context"].to_numpy(int)
        if has_truth:
            mf = metrics.context_metrics(t, terrain, final, excluded_labels=excluded)
            summary["final_clustering"] = {
                "ari": finite_or_none(mf.ari),
                "noise_fraction": finite_or_none(mf.noise_fraction),
                "contexts": int(mf.n_contexts),
            }
        else:
            summary["final_clustering"] = {
                "ari": None,
                "noise_fraction": float(np.mean(final < 0)),
                "contexts": len({int(c) for c in final if c >= 0}),
            }
    return summary


def _settle_row(entry: Mapping[str, Any] | None) -> str:
    if not entry or not entry.get("contexts_scored"):
        return "- (no context reached 20 s)"
    text = f"mean {entry['worst_mean']:.3f}, max {entry['worst_max']:.3f}"
    text += f" ({entry['contexts_scored']} contexts scored"
    if entry.get("contexts_unscored"):
        text += f"; not scored: {', '.join(str(i) for i in entry['contexts_unscored'])}"
    return text + ")"


def _failures_row(summary: Mapping[str, Any]) -> str:
    """The count of catastrophic failures and, for each, its time and reason."""
    events = summary.get("failure_events") or []
    count = summary.get("catastrophic_failures")
    if count is None:
        return "-"
    if not events:
        return str(count)
    shown = "; ".join(
        f"t={e['t_s']:.1f} s {e.get('detail') or e.get('kind')}"
        if e.get("t_s") is not None
        else str(e.get("detail") or e.get("kind"))
        for e in events[:3]
    )
    more = f"; {len(events) - 3} more" if len(events) > 3 else ""
    return f"{count} ({shown}{more})"


def _station_faults(status: Mapping[str, Any]) -> str:
    """``"no faults"`` or the rejections and timeouts per stream of a ``station_status`` dict."""
    parts = []
    for name, stream in status.get("streams", {}).items():
        counts = dict(stream.get("rejected", {}))
        if stream.get("timeouts"):
            counts["timeouts"] = stream["timeouts"]
        if counts:
            parts.append(f"{name}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    return "; ".join(parts) if parts else "no faults"


def _limit_flag(entry: Mapping[str, Any]) -> str:
    """The identifiability column: whether the data came near the friction limit."""
    if entry.get("fitted") is False:
        return "no fit (" + str(entry.get("fit_status") or "prior") + ")"
    if entry.get("near_limit") is None:
        return "-"
    if entry.get("untrusted"):
        return f"fit not trustworthy: {entry['untrusted']} (not identifiable)"
    if entry.get("below_used"):
        return "peak fitted below the used friction (not identifiable)"
    if not entry["near_limit"]:
        return "never near (mu not identifiable)"
    return "near" if entry.get("identifiable") else "near, std large"


def summary_table(summary: Mapping[str, Any]) -> str:
    """The summary as a plain-text table for the terminal."""

    def fmt(v, unit: str = "") -> str:
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.3f}{unit}"
        return f"{v}{unit}"

    s = summary
    reid = [e["latency_s"] for e in s.get("reidentification_latency_s", [])]
    rows = [
        ("scenario", s.get("scenario")),
        ("simulated time", fmt(s.get("sim_time_s"), " s")),
        ("wall time", fmt(s.get("wall_time_s"), " s")),
        ("real-time factor", fmt(s.get("realtime_factor"), "x")),
        ("real-time factor (CPU time)", fmt(s.get("realtime_factor_cpu"), "x")),
        ("laps completed", fmt(s.get("laps_completed"))),
        ("lap time", fmt(s.get("lap_time_s"), " s")),
        ("mean speed", fmt(s.get("mean_speed_mps"), " m/s")),
        (
            "lateral error rms / max",
            f"{fmt(s.get('lateral_error_rms_m'))} / {fmt(s.get('max_abs_lateral_error_m'), ' m')}",
        ),
        ("catastrophic failures", _failures_row(s)),
        ("contexts discovered", fmt(s.get("contexts_discovered"))),
        ("true terrains visited", ", ".join(s.get("true_terrains_visited", [])) or "-"),
        ("ARI (online ids)", fmt(s.get("ari"))),
        ("noise fraction (online)", fmt(s.get("noise_fraction"))),
        ("ARI (final clustering)", fmt(s.get("final_clustering", {}).get("ari"))),
        ("noise (final clustering)", fmt(s.get("final_clustering", {}).get("noise_fraction"))),
        ("re-identification latency", ", ".join(fmt(x, " s") for x in reid) or "-"),
        (
            "time to first id",
            ", ".join(f"{k} {fmt(v, ' s')}" for k, v in s.get("new_terrain_latency_s", {}).items())
            or "-",
        ),
        ("mu error (time-weighted)", fmt(s.get("mu_abs_error_time_weighted"))),
        (
            "mu error after 20 s, worst context",
            _settle_row(s.get("mu_error_after_settle")),
        ),
    ]
    if s.get("ground_truth") is False:
        rows.insert(1, ("ground truth", "none: " + NO_TRUTH_NOTE.split(": ", 1)[1]))
    if s.get("station_status"):
        st = s["station_status"]
        rows.insert(1, ("station", f"{st.get('source')} ({_station_faults(st)})"))
    if s.get("interrupted"):
        rows.insert(1, ("status", "interrupted (summary of what was logged)"))
    width = max(len(r[0]) for r in rows)
    lines = [f"{name.ljust(width)}  {value}" for name, value in rows]
    est = s.get("mu_estimates", [])
    if est:
        lines.append("")
        lines.append(
            "context  terrain        mu_true  mu_hat   handed   std      |err|    "
            "after 20 s: mean  max      scored  time     mu >=   limit"
        )
        for e in est:
            fitted = e.get("fitted", True)
            lines.append(
                f"{e['id']:>7}  {str(e['majority_terrain'] or '-'):<13}  "
                f"{fmt(e['true_mu']):>7}  {fmt(e['mu_hat']) if fitted else 'no fit':>7}  "
                f"{fmt(e.get('handed_mu')):>7}  {fmt(e['std']):>7}  "
                f"{fmt(e['abs_error']):>7}  {fmt(e['abs_error_after_settle_mean']):>16}  "
                f"{fmt(e.get('abs_error_after_settle_max')):>7}  "
                f"{e.get('scored_time_s', 0.0):>6.1f} s  {e['time_in_context_s']:>6.1f} s  "
                f"{fmt(e.get('mu_lower_bound')):>6}  {_limit_flag(e)}"
            )
    return "\n".join(lines)
