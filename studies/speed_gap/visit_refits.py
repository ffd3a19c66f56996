"""One terrain visit's samples through the fitter's incremental refits, as the loop runs them
(every PERIOD s on the samples so far), against the batch fit of the whole visit: whether the
online estimate lags its own optimum, and how it climbs over the visit.

Input: a ``pcvfe simulate`` run folder (``fitter_samples.npz``: the fitter's 100 Hz samples;
``drive_log.csv``: the terrain under the car), e.g. ``pcvfe simulate paper_eval --no-meshcat
--out DIR``. The visit is cut by the terrain labels, not the clustering's contexts.

Usage: python studies/speed_gap/visit_refits.py RUN [--terrains brick,concrete] [--period 1]
           [--vehicle ford_escort] [--mapping lateral_peak]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.estimation.context_estimator import effect_fitter
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.models.effect_model import load_model_file, vehicle_model_path
from pcvfe_drake.vehicle.params import load_vehicle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--terrains", default="brick,concrete,sand,patchy_grass")
    ap.add_argument("--period", type=float, default=1.0, help="refit period [s]")
    ap.add_argument("--vehicle", default="ford_escort")
    ap.add_argument("--mapping", default="lateral_peak")
    args = ap.parse_args()
    samples = np.load(args.run / "fitter_samples.npz")
    t_all, s_all, u_all = samples["t_s"], samples["state"], samples["actuation"]
    log = pd.read_csv(args.run / "drive_log.csv", usecols=["t", "terrain", "mu_true"])
    row = np.clip(np.searchsorted(log["t"].to_numpy(), t_all), 0, len(log) - 1)
    labels = log["terrain"].to_numpy()[row]
    vp = load_vehicle(args.vehicle)
    model = load_model_file(vehicle_model_path(args.vehicle, "mb", args.mapping))
    cfg = LiveFitConfig(model=model)

    def fitter(iterations: int):  # the online fitter, at ``iterations`` per refit
        return effect_fitter(vp, dataclasses.replace(cfg, max_iterations=iterations))

    out = {}
    for terrain in args.terrains.split(","):
        idx = np.flatnonzero(labels == terrain)
        if idx.size < 200:
            continue
        t, s, u = t_all[idx], s_all[idx], u_all[idx]
        mu_true = float(log["mu_true"].to_numpy()[row[idx]][0])
        online, info, previous, history = fitter(cfg.max_iterations), None, None, []
        for end in np.arange(t[0] + args.period, t[-1] + 1e-9, args.period):
            n = int(np.searchsorted(t, end, side="right"))
            res, info = online.refit(t[:n], s[:n], u[:n], info, vp.mu, previous)
            if res is not None:
                previous = res.model_theta
                history.append((round(float(end - t[0]), 2), round(float(res.theta[0]), 4)))
        batch = fitter(20)(t, s, u, None, vp.mu)
        out[terrain] = {
            "true_mu": mu_true,
            "visit_s": round(float(t[-1] - t[0]), 2),
            "incremental_last": history[-1][1] if history else None,
            "batch": round(float(batch.theta[0]), 4),
            "batch_std": round(float(batch.std[0]), 4),
            "history": history,
        }
        every = max(1, len(history) // 8)
        print(
            f"{terrain:13s} (mu {mu_true:.2f}, {out[terrain]['visit_s']:.1f} s): incremental "
            f"{out[terrain]['incremental_last']}, batch {out[terrain]['batch']} +- "
            f"{out[terrain]['batch_std']}; over the visit {history[::every]}"
        )
    print(json.dumps({"study": "speed_gap.visit_refits", "run": str(args.run), "visits": out}))


if __name__ == "__main__":
    main()
