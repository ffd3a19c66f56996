"""Per terrain entry of finished runs: how long a new terrain waited for an id, a fit, the truth
(``pcvfe evaluate --report DIR --entry-latency``; no pydrake).

For a run folder (``pcvfe simulate ... --out DIR`` or an experiment's ``runs/<run>``) and every
entry into a terrain (transition strips and the start excluded), from the drive log, the
summary's first-fit times and the course (recomputed from the log, so runs made before
summary.json carried these numbers read alike; ``runs.drive_metrics.transition_response``):

- ``id``: seconds from the entry until the visit's context was first reported;
- ``fit``: until that context had its first fit;
- ``within``: until the friction handed to the NMPC was within 0.05 of the truth (None: never
  during the visit);
- ``lat``: the largest |lateral error| over the visit [m].

Against a reference run of the same seed (usually the oracle's), :func:`terrain_lag` gives per
visit of a terrain (the start's and the transition strips' included) the seconds the run took
over the stretch of course it drove on that visit minus the reference's over the same stretch,
at the same arc length (progress from the true position projected on the course): where a lap
loses its time. The lags of a run sum to the time lost over the distance it drove.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from pcvfe_drake.control.course import load_course
from pcvfe_drake.runs import drive_metrics
from pcvfe_drake.runs.summary import lateral_error_rows

LATENCIES = ("id", "fit", "within")
"""The three waits of an entry, in the order they happen."""


def _round(x, digits: int = 2):
    return None if x is None else round(float(x), digits)


def _ratio(a, b):
    return None if a is None or b is None or not b else round(float(a) / float(b), 4)


def read_run(folder: Path) -> tuple[dict, pd.DataFrame, object]:
    """A run folder's summary, drive log (Parquet or CSV) and course; a one-line error naming
    the file when one is missing."""
    folder = Path(folder)
    for name in ("summary.json", "scenario.yaml"):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"{folder}: no {name} (not a run folder)")
    parquet, csv = folder / "drive_log.parquet", folder / "drive_log.csv"
    if parquet.is_file():
        log = pd.read_parquet(parquet)
    elif csv.is_file():
        log = pd.read_csv(csv)
    else:
        raise FileNotFoundError(f"{folder}: no drive_log.parquet or drive_log.csv")
    summary = json.loads((folder / "summary.json").read_text())
    scenario = yaml.safe_load((folder / "scenario.yaml").read_text()) or {}
    return summary, log, run_course(scenario)


def run_course(scenario: dict):
    """The course a stored run drove: its scenario's ``course``, else its world's own (a
    generated world brings its course file), else the default course."""
    from pcvfe_drake.diagrams.world_io import course_to_drive

    return load_course(course_to_drive(scenario.get("course") or "", scenario.get("world")) or None)


def run_entries(folder: Path) -> dict:
    """The entries of one run (the module docstring) with its speed, lap time and failures."""
    summary, log, course = read_run(folder)
    first_fit = {
        int(e["id"]): float(e["first_fit_s"])
        for e in summary.get("mu_estimates", [])
        if e.get("first_fit_s") is not None
    }
    response = drive_metrics.transition_response(
        log,
        tuple(summary.get("excluded_terrains", [])),
        first_fit_s=first_fit,
        lateral_error_m=lateral_error_rows(drive_metrics.truth_frame(log), course),
    )
    entries = [
        {
            "terrain": e["terrain"],
            "t_enter_s": round(e["t_enter_s"], 2),
            "visit_s": round(e["visit_s"], 2),
            "id": _round(e.get("context_id_s")),
            "fit": _round(e.get("first_fit_s")),
            "within": _round(e["response_s"]),
            "lat": _round(e.get("max_abs_lateral_error_m")),
        }
        for e in response["entries"]
    ]
    return {
        "run": Path(folder).name,
        "seed": summary.get("seed"),
        "mean_speed_mps": _round(summary.get("mean_speed_mps")),
        "lap_time_s": _round(summary.get("lap_time_s")),
        "max_abs_lateral_error_m": _round(summary.get("max_abs_lateral_error_m")),
        "failures": summary.get("catastrophic_failures"),
        "entries": entries,
    }


def _progress_m(log: pd.DataFrame, course) -> np.ndarray:
    """Cumulative progress [m] along ``course`` of each row's true position."""
    xy = drive_metrics.truth_frame(log)[["sx", "sy"]].to_numpy(float)
    return course.unwrap_progress(course.project(xy).s)


def terrain_lag(run: Path, reference: Path, splits_s: Sequence[float] = ()) -> dict:
    """Seconds ``run`` lost to ``reference`` per terrain visit at the same arc length, and its
    speed and lap time as fractions of the reference's. ``splits_s``: each visit also gets
    ``lag_first_s``, the seconds lost in its first ``split`` seconds per split (keyed
    ``f"{split:g}"``; a visit shorter than a split: its whole lag)."""
    logs, course, summaries = [], None, []
    for folder in (run, reference):
        summary, log, course_here = read_run(folder)
        course = course or course_here
        summaries.append(summary)
        logs.append(log[np.all(np.isfinite(log[["true_sx", "true_sy"]].to_numpy(float)), axis=1)])
    log, ref = logs
    p, t = _progress_m(log, course), log["t"].to_numpy(float)
    p_ref, t_ref = _progress_m(ref, course), ref["t"].to_numpy(float)
    keep = np.concatenate([[True], np.diff(p_ref) > 0])  # interpolation needs rising progress
    p_ref, t_ref = np.maximum.accumulate(p_ref[keep]), t_ref[keep]
    terrain = log["terrain"].astype(str).to_numpy()
    visits = []
    for a, b, name in drive_metrics._visits(terrain, ()):
        b = min(b, len(t) - 1)
        if p[b] > p_ref[-1]:  # beyond the reference's log
            continue

        def lag(i: int, j: int) -> float:
            ref_s = float(np.interp(p[j], p_ref, t_ref) - np.interp(p[i], p_ref, t_ref))
            return round(float(t[j] - t[i]) - ref_s, 2)

        visit = {
            "terrain": name,
            "t_enter_s": round(float(t[a]), 2),
            "run_s": round(float(t[b] - t[a]), 2),
            "lag_s": lag(a, b),
        }
        if splits_s:
            visit["lag_first_s"] = {
                f"{x:g}": lag(a, min(a + int(np.searchsorted(t[a : b + 1], t[a] + x)), b))
                for x in splits_s
            }
        visits.append(visit)
    mine, theirs = summaries
    return {
        "reference": Path(reference).name,
        "speed_ratio": _ratio(mine.get("mean_speed_mps"), theirs.get("mean_speed_mps")),
        "lap_ratio": _ratio(mine.get("lap_time_s"), theirs.get("lap_time_s")),
        "lag_total_s": round(sum(v["lag_s"] for v in visits), 2),
        "visits": visits,
    }


def per_terrain(runs: Sequence[dict]) -> dict[str, dict]:
    """Per terrain over ``runs``: entries, the mean of each latency (a "never" counts as the
    visit's length, so a run that never got there is not scored better than a slow one), how
    many never got there, and the largest lateral error; with lags, their mean and range."""
    out: dict[str, dict] = {}
    for name in sorted({e["terrain"] for r in runs for e in r["entries"]}):
        entries = [e for r in runs for e in r["entries"] if e["terrain"] == name]
        row: dict = {"entries": len(entries)}
        for key in LATENCIES:
            vals = [e["visit_s"] if e[key] is None else e[key] for e in entries]
            row[f"{key}_mean_s"] = _round(np.mean(vals))
            row[f"{key}_never"] = sum(e[key] is None for e in entries)
        row["lat_max_m"] = _round(max((e["lat"] or 0.0) for e in entries))
        out[name] = row
    lags: dict[str, list[float]] = {}
    for r in runs:
        per_run: dict[str, float] = {}
        for v in (r.get("lag") or {}).get("visits", []):
            per_run[v["terrain"]] = per_run.get(v["terrain"], 0.0) + v["lag_s"]
        for name, lag in per_run.items():
            lags.setdefault(name, []).append(lag)
    for name, values in lags.items():
        row = out.setdefault(name, {"entries": 0})
        row["lag_per_run_mean_s"] = _round(np.mean(values))
        row["lag_per_run_range_s"] = [_round(min(values)), _round(max(values))]
    return out


def experiment_entries(root: Path, against: str | None = None) -> dict:
    """Every run of an experiment folder (``runs/<scenario>__<source>__sNNN``), grouped by
    scenario and source, with each group's :func:`per_terrain`; ``against``: a source whose run
    of the same scenario and seed is the reference of :func:`terrain_lag`."""
    runs_dir = Path(root) / "runs"
    folders = sorted(p for p in runs_dir.glob("*__*__s*") if (p / "summary.json").is_file())
    if not folders:
        raise FileNotFoundError(f"{runs_dir}: no finished runs (runs/<run>/summary.json)")
    parsed = {}
    for folder in folders:
        scenario, source, seed = folder.name.rsplit("__", 2)
        parsed[folder] = (scenario, source, seed)
    sources = {s for _, s, _ in parsed.values()}
    if against is not None and against not in sources:
        raise ValueError(f"--against {against}: no runs of that source in {runs_dir}")
    groups: dict[str, dict] = {}
    for folder, (scenario, source, seed) in parsed.items():
        if source == against:
            continue
        entry = run_entries(folder)
        if against is not None:
            ref = runs_dir / f"{scenario}__{against}__{seed}"
            if (ref / "summary.json").is_file():
                entry["lag"] = terrain_lag(folder, ref)
        groups.setdefault(f"{scenario} / {source}", {"runs": []})["runs"].append(entry)
    for group in groups.values():
        group["per_terrain"] = per_terrain(group["runs"])
    return {"against": against, "groups": groups}


def markdown(result: dict) -> str:
    """The tables of :func:`experiment_entries` as Markdown."""
    lines = ["# Terrain entries", ""]
    lines.append(
        "Per terrain: the mean seconds from entering it until its context had an id, a first "
        "fit, and the handed mu within 0.05 of the truth (a never counts as the visit's length; "
        "never = visits that never got there), and the largest lateral error of its visits."
    )
    if result["against"]:
        lines.append(
            f"lost = seconds per run lost to {result['against']} of the same seed on that "
            "terrain's visits, at the same arc length (mean and range over runs)."
        )
    for name, group in result["groups"].items():
        lines += ["", f"## {name}", ""]
        head = ["terrain", "entries", "id [s]", "fit [s]", "within 0.05 [s]", "lat max [m]"]
        head += ["lost [s]"] if result["against"] else []
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + "---|" * len(head))
        for terrain, row in group["per_terrain"].items():
            cells = [terrain, str(row["entries"])]
            for key in LATENCIES:
                if f"{key}_mean_s" not in row:
                    cells.append("-")
                    continue
                never = row[f"{key}_never"]
                cells.append(f"{row[f'{key}_mean_s']}" + (f" ({never} never)" if never else ""))
            cells.append(str(row.get("lat_max_m", "-")))
            if result["against"]:
                lo_hi = row.get("lag_per_run_range_s")
                cells.append(
                    f"{row['lag_per_run_mean_s']} [{lo_hi[0]}, {lo_hi[1]}]" if lo_hi else "-"
                )
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_entry_latency(root: Path, against: str | None = None) -> tuple[Path, Path, str]:
    """Write ``entry_latency.json`` and ``entry_latency.md`` into the experiment folder."""
    result = experiment_entries(root, against)
    text = markdown(result)
    json_path, md_path = Path(root) / "entry_latency.json", Path(root) / "entry_latency.md"
    json_path.write_text(json.dumps(result, indent=1) + "\n")
    md_path.write_text(text)
    return json_path, md_path, text
