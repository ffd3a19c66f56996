"""Offline fits of the calibrated effect model on terrain visits of closed-loop laps: the visit's
first SPAN seconds and the whole visit, with the car's model as shipped and with one held
constant changed (which constant the peak's reading depends on).

Input: a ``pcvfe evaluate`` folder whose ``runs/<scenario>__<source>__sNNN/drive_log.parquet``
hold the measured states at the log rate (20 Hz) and the terrain under the car. Each fit is
``EffectFitter``'s batch fit (all the span's 1 s windows, 10 iterations, from the nominal mu),
on the rows of one terrain, as the terrain labels (not the clustering's contexts) cut them.

Usage: python studies/speed_gap/visit_fits.py DIR [--seeds 0,1,2,3] [--spans 10,20]
           [--variants shipped,s_drive_0.4,...] [--vehicle ford_escort] [--mapping lateral_peak]
Last stdout line: one JSON object (per variant, span and terrain: mean fitted / true mu).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.estimation.effect_fit import EffectFitter
from pcvfe_drake.models.effect_model import load_model_file, vehicle_model_path
from pcvfe_drake.vehicle.params import load_vehicle

STATES = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]
CHANGES = {
    "shipped": {},
    "s_drive_0": {"wheel_force_steer": {"s_drive": 0.0}},
    "s_drive_0.4": {"wheel_force_steer": {"s_drive": 0.4}},
    "s_drive_0.6": {"wheel_force_steer": {"s_drive": 0.6}},
    "k_drag_0": {"wheel_force_steer": {"k_drag": 0.0}},
    "no_wheel_force_steer": {"wheel_force_steer": None},
    "axle_1.01_1.24": {"axle_stiffness": {"k_f": 1.01, "k_r": 1.24}},
    "no_axle_stiffness": {"axle_stiffness": None},
    "k_lt_-0.85": {"track_slip": {"k_lt": -0.85}},
}
"""The variants: a held effect's constants replaced (None: the effect left out). The axle
factors 1.01 / 1.24 and k_lt -0.85 are the ones fitted on multi-body replays of the evaluation
lap before the car was calibrated."""


def effects_of(model, change: dict) -> list[dict]:
    out = []
    for effect in model.effects:
        entry = {"name": effect.name, "fixed": dict(effect.fixed or {})}
        if effect.name in change:
            if change[effect.name] is None:
                continue
            entry["fixed"].update(change[effect.name])
        out.append(entry)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", type=Path)
    ap.add_argument("--scenario", default="paper_eval")
    ap.add_argument("--source", default="pcvfe")
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--spans", default="10,20", help="first seconds of each visit (and whole)")
    ap.add_argument("--variants", default="shipped")
    ap.add_argument("--vehicle", default="ford_escort")
    ap.add_argument("--mapping", default="lateral_peak")
    args = ap.parse_args()
    vp = load_vehicle(args.vehicle)
    model = load_model_file(vehicle_model_path(args.vehicle, "mb", args.mapping))
    spans = [float(s) for s in args.spans.split(",") if s] + [float("inf")]
    ratios: dict = {}
    for seed in (int(s) for s in args.seeds.split(",")):
        folder = args.root / "runs" / f"{args.scenario}__{args.source}__s{seed:03d}"
        log = pd.read_parquet(folder / "drive_log.parquet")
        for terrain, rows in log.groupby("terrain", sort=True):
            t = rows["t"].to_numpy(float)
            if t.size < 200 or np.any(np.diff(t) > 0.5):  # one visit, long enough
                continue
            mu_true = float(rows["mu_true"].median())
            for name in args.variants.split(","):
                fitter = EffectFitter(
                    vp, effects_of(model, CHANGES[name]), max_windows=1000, max_iterations=10
                )
                for span in spans:
                    n = int(np.searchsorted(t, t[0] + span))
                    if span < float("inf") and n >= t.size:
                        continue
                    res = fitter(
                        t[:n],
                        rows[STATES].to_numpy()[:n],
                        rows[["steer_rate", "accel"]].to_numpy()[:n],
                        None,
                        vp.mu,
                    )
                    if res is None:
                        continue
                    key = "whole" if span == float("inf") else f"first_{span:g}_s"
                    cell = ratios.setdefault(name, {}).setdefault(key, {})
                    cell.setdefault(terrain, []).append(float(res.theta[0]) / mu_true)
        print(f"seed {seed} done", flush=True)
    summary = {
        name: {
            key: {tr: round(float(np.mean(v)), 3) for tr, v in sorted(cells.items())}
            for key, cells in by_span.items()
        }
        for name, by_span in ratios.items()
    }
    for name, by_span in summary.items():
        for key, cells in by_span.items():
            print(f"{name:22s} {key:12s} fitted / true: {cells}")
    print(json.dumps({"study": "speed_gap.visit_fits", "root": str(args.root), "ratios": summary}))


if __name__ == "__main__":
    main()
