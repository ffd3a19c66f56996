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

Usage: python benchmarks/terrain_entry_latency.py [RUN_DIR ...] [--quick] [--scenario S]
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
    ap.add_argument("--scenario", default="paper_eval_effects", help="without runs: this one")
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
        runs.append(run_entries(folder))
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
    result = {"benchmark": "terrain_entry_latency", "per_terrain": per_terrain(runs), "runs": runs}
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
