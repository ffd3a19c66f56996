"""Why the unknown-context policy changes the tracking error: one lap per policy, split by phase.

One lap of a scenario (default ``paper_sim``), same seed, two settings of what PC-VFE hands the
NMPC while the terrain is unknown (``fitter.handing.unknown``): ``!Prior`` (mu 1.05, nominal
stiffness) and ``!Conservative`` keeping the prior's ``mu * C_S`` (the default; lowering mu alone,
the third setting this study once compared, is no longer a setting). Per run: mean speed, lateral
error RMS and max on the true state, the RMS split by whether mu_hat was below the true mu
by more than 0.05 (the policy at work on a grippier terrain), within 0.05, or above, the
time-weighted mu error and the peak friction utilisation.

Usage: python studies/unknown_policy_tracking/unknown_policy_tracking.py
       [--quick] [--scenario paper_sim] [--seed 0]
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.diagrams.run_simulation import simulate_summary
from pcvfe_drake.diagrams.scenario_io import load_scenario
from pcvfe_drake.diagrams.world_io import scenario_course
from pcvfe_drake.handing.config import Conservative, Prior

SETTINGS = {
    "prior": {"fitter.handing.unknown": Prior()},
    "conservative": {"fitter.handing.unknown": Conservative()},
}
TOL = 0.05


def phases(log: pd.DataFrame, course) -> dict:
    xy = log[["true_sx", "true_sy"]].to_numpy(float)
    lat = np.asarray(course.project(xy, heading=log["true_psi"].to_numpy(float)).lateral_error)
    t = log["t"].to_numpy(float)
    diff = log["mu_hat"].to_numpy(float) - log["mu_true"].to_numpy(float)
    out = {}
    for name, rows in (
        ("under", diff < -TOL),
        ("within", np.abs(diff) <= TOL),
        ("over", diff > TOL),
    ):
        out[name] = {
            "time_s": round(float(rows.sum() * np.median(np.diff(t))), 1),
            "lateral_rms_m": round(float(np.sqrt(np.mean(lat[rows] ** 2))), 4)
            if rows.any()
            else None,
        }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the first 60 s only")
    parser.add_argument("--scenario", default="paper_sim")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    length = {"duration_s": 60.0} if args.quick else {"laps": 1.0}
    course = scenario_course(load_scenario(args.scenario))
    result: dict = {"scenario": args.scenario, "seed": args.seed}
    for key, overrides in SETTINGS.items():
        with tempfile.TemporaryDirectory() as tmp:
            s = simulate_summary(args.scenario, args.seed, {**length, **overrides}, out=tmp)
            columns = ["t", "true_sx", "true_sy", "true_psi", "mu_hat", "mu_true"]
            log = pd.read_csv(Path(tmp) / "drive_log.csv", usecols=columns)
        result[key] = {
            "mean_speed_mps": round(s["mean_speed_mps"], 3),
            "lateral_error_rms_m": round(s["lateral_error_rms_m"], 4),
            "max_abs_lateral_error_m": round(s["max_abs_lateral_error_m"], 4),
            "mu_abs_error_time_weighted": round(s["mu_abs_error_time_weighted"], 4),
            "friction_utilisation_max": round(s["friction_utilisation"]["max"], 3),
            "catastrophic_failures": s["catastrophic_failures"],
            "by_mu_hat": phases(log, course),
        }
        print(f"{key}: {json.dumps(result[key])}", flush=True)
    result["rms_ratio_softer_over_kept"] = round(
        result["conservative_softer_tyres"]["lateral_error_rms_m"]
        / result["conservative"]["lateral_error_rms_m"],
        2,
    )
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
