"""Per terrain entry of finished runs: how long the new terrain waited for an id, a fit, the truth.

For every run folder given (``pcvfe simulate ... --out DIR`` or an experiment's ``runs/*``) and
every entry into a terrain (transition strips and the start excluded), from the drive log, the
summary's first-fit times and the course (recomputed, so runs made before summary.json carried
these numbers are read alike; ``pcvfe_drake.runs.drive_metrics.transition_response``):

- ``id``: seconds from the entry until the visit's context was first reported;
- ``fit``: until that context had its first fit;
- ``within``: until the friction handed to the NMPC was within 0.05 of the truth (None: never
  during the visit);
- ``lat``: the largest |lateral error| over the visit [m].

Plus each run's mean speed, lap time and largest lateral error, and per terrain the mean of the
three latencies over the runs (a "never" counts as the visit's length).

``--oracle DIR``: a folder of reference runs (an experiment's ``runs/``, or one run) made with
another friction source, usually the oracle: each run is compared with the reference run of its
seed (the folder whose name ends in ``__sNNN``, or the one run given) at the same arc length:
``lag``, per visit of a terrain (the start's and the transition strips' included, the lap's end
being the start's terrain again), the seconds the run took over the stretch of course it drove on
that visit minus the reference's over the same stretch (progress from the true position projected
on the course), and its speed and lap time as a fraction of the reference's. The lags of a run
sum to its lap's time lost over the driven distance.

Usage: python benchmarks/terrain_entry_latency.py [RUN_DIR ...] [--quick] [--scenario S]
[--oracle DIR]
Without run folders it makes one: ``pcvfe simulate SCENARIO --seed 0`` (default
``paper_eval_effects``; one lap, 1-3 min; ``--quick``: the first 45 s, one terrain entry).
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from _own_run import make_run

from pcvfe_drake.control.course import load_course
from pcvfe_drake.runs import drive_metrics
from pcvfe_drake.runs.summary import lateral_error_rows


def run_entries(folder: Path) -> dict:
    summary = json.loads((folder / "summary.json").read_text())
    parquet = folder / "drive_log.parquet"
    log = pd.read_parquet(parquet) if parquet.is_file() else pd.read_csv(folder / "drive_log.csv")
    scenario = yaml.safe_load((folder / "scenario.yaml").read_text())
    course = load_course(scenario.get("course") or None)
    first_fit = {
        int(e["id"]): float(e["first_fit_s"])
        for e in summary.get("mu_estimates", [])
        if e.get("first_fit_s") is not None
    }
    excluded = tuple(summary.get("excluded_terrains", []))
    response = drive_metrics.transition_response(
        log,
        excluded,
        first_fit_s=first_fit,
        lateral_error_m=lateral_error_rows(drive_metrics.truth_frame(log), course),
    )
    rows = []
    for e in response["entries"]:
        rows.append(
            {
                "terrain": e["terrain"],
                "t_enter_s": round(e["t_enter_s"], 2),
                "visit_s": round(e["visit_s"], 2),
                "id": _round(e.get("context_id_s")),
                "fit": _round(e.get("first_fit_s")),
                "within": _round(e["response_s"]),
                "lat": _round(e.get("max_abs_lateral_error_m")),
            }
        )
    return {
        "run": folder.name,
        "seed": summary.get("seed"),
        "mean_speed_mps": _round(summary.get("mean_speed_mps")),
        "lap_time_s": _round(summary.get("lap_time_s")),
        "max_abs_lateral_error_m": _round(summary.get("max_abs_lateral_error_m")),
        "failures": summary.get("catastrophic_failures"),
        "entries": rows,
    }


def progress_m(log: pd.DataFrame, course) -> np.ndarray:
    """Cumulative progress [m] along ``course`` of each row's true position (NaN-free rows)."""
    truth = drive_metrics.truth_frame(log)
    xy = truth[["sx", "sy"]].to_numpy(float)
    s = course.project(xy).s
    return course.unwrap_progress(s)


def terrain_lag(run: Path, reference: Path) -> dict:
    """Time [s] ``run`` lost to ``reference`` per terrain visit at the same arc length (the
    module docstring)."""
    logs, course = [], None
    for folder in (run, reference):
        parquet = folder / "drive_log.parquet"
        log = (
            pd.read_parquet(parquet) if parquet.is_file() else pd.read_csv(folder / "drive_log.csv")
        )
        if course is None:
            scenario = yaml.safe_load((folder / "scenario.yaml").read_text())
            course = load_course(scenario.get("course") or None)
        logs.append(log[np.all(np.isfinite(log[["true_sx", "true_sy"]].to_numpy(float)), axis=1)])
    log, ref = logs
    p, t = progress_m(log, course), log["t"].to_numpy(float)
    p_ref, t_ref = progress_m(ref, course), ref["t"].to_numpy(float)
    keep = np.concatenate([[True], np.diff(p_ref) > 0])  # interpolation needs rising progress
    p_ref, t_ref = np.maximum.accumulate(p_ref[keep]), t_ref[keep]
    terrain = log["terrain"].astype(str).to_numpy()
    rows = []
    for a, b, name in drive_metrics._visits(terrain, ()):
        b = min(b, len(t) - 1) if b < len(t) else b - 1
        pa, pb = p[a], p[b]
        if pb > p_ref[-1]:  # beyond the reference's log
            continue
        ref_s = float(np.interp(pb, p_ref, t_ref) - np.interp(pa, p_ref, t_ref))
        rows.append(
            {
                "terrain": name,
                "t_enter_s": round(float(t[a]), 2),
                "run_s": round(float(t[b] - t[a]), 2),
                "lag_s": round(float(t[b] - t[a]) - ref_s, 2),
            }
        )
    ref_summary = json.loads((reference / "summary.json").read_text())
    summary = json.loads((run / "summary.json").read_text())
    return {
        "reference": reference.name,
        "speed_ratio": _ratio(summary.get("mean_speed_mps"), ref_summary.get("mean_speed_mps")),
        "lap_ratio": _ratio(summary.get("lap_time_s"), ref_summary.get("lap_time_s")),
        "lag_total_s": round(sum(r["lag_s"] for r in rows), 2),
        "visits": rows,
    }


def _ratio(a, b):
    return None if a is None or b is None or not b else round(float(a) / float(b), 4)


def reference_run(folder: Path, seed) -> Path | None:
    """The reference run for ``seed`` in ``folder`` (itself when it is one run)."""
    if (folder / "summary.json").is_file():
        return folder
    if seed is None:
        return None
    found = sorted(folder.glob(f"*__s{int(seed):03d}"))
    return found[0] if found else None


def _round(x, digits: int = 2):
    return None if x is None else round(float(x), digits)


def per_terrain(runs: list[dict]) -> dict:
    out: dict[str, dict] = {}
    for name in sorted({e["terrain"] for r in runs for e in r["entries"]}):
        entries = [e for r in runs for e in r["entries"] if e["terrain"] == name]
        row = {"entries": len(entries)}
        for key in ("id", "fit", "within"):
            vals = [e["visit_s"] if e[key] is None else e[key] for e in entries]
            row[f"{key}_mean_s"] = _round(np.mean(vals))
            row[f"{key}_never"] = sum(e[key] is None for e in entries)
        row["lat_max_m"] = _round(max((e["lat"] or 0.0) for e in entries))
        out[name] = row
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", type=Path, help="run folders with summary.json")
    ap.add_argument("--quick", action="store_true", help="without runs: a 45 s run")
    ap.add_argument("--scenario", default="paper_eval", help="without runs: this one")
    ap.add_argument(
        "--oracle", type=Path, help="reference runs (a folder of runs, or one run): per-terrain lag"
    )
    args = ap.parse_args(argv)
    if not args.runs:
        with tempfile.TemporaryDirectory(prefix="entry_latency_") as tmp:
            made = make_run(Path(tmp) / "run", args.scenario, 45.0 if args.quick else None)
            return main([str(made)])
    runs = []
    for folder in args.runs:
        if not (folder / "summary.json").is_file():
            print(f"{folder}: no summary.json; pass run folders (pcvfe simulate --out DIR)")
            return 2
        entry = run_entries(folder)
        if args.oracle is not None:
            ref = reference_run(args.oracle, entry["seed"])
            if ref is None:
                print(f"{args.oracle}: no reference run for seed {entry['seed']}")
                return 2
            entry["lag"] = terrain_lag(folder, ref)
        runs.append(entry)
    for r in runs:
        print(
            f"{r['run']}: {r['mean_speed_mps']} m/s, lap {r['lap_time_s']} s, "
            f"lat max {r['max_abs_lateral_error_m']} m, failures {r['failures']}"
        )
        for e in r["entries"]:
            print(
                f"  {e['terrain']:14s} t={e['t_enter_s']:7.2f}  id {e['id']}  fit {e['fit']}  "
                f"within {e['within']}  lat {e['lat']}"
            )
        if "lag" in r:
            lag = r["lag"]
            print(
                f"  vs {lag['reference']}: speed {lag['speed_ratio']}, lap {lag['lap_ratio']}, "
                f"lost {lag['lag_total_s']} s: "
                + ", ".join(
                    f"{v['terrain']}@{v['t_enter_s']:.0f} {v['lag_s']:+.1f}" for v in lag["visits"]
                )
            )
    result = {"benchmark": "terrain_entry_latency", "per_terrain": per_terrain(runs), "runs": runs}
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
