"""Coverage of the fitter's 95 % friction intervals, offline, on saved closed-loop runs.

For every run folder given (``pcvfe simulate`` / ``pcvfe evaluate`` output: ``drive_log.parquet``
with the final clustering's labels ``final_context``, ``summary.json`` with each context's
majority terrain and its true mu, ``scenario.yaml``), each context's final buffer (its newest
``fitter.buffer_s`` of logged samples) is refitted as the live fitter refits it: with the
scenario's effect model (``fitter.effects``: ``EffectFitter`` with the scenario's windows) or the
single-track fit (windows of the live horizon and stride in seconds at the log's rate, the newest
``fitter.max_windows``), each with the ``iid`` and the ``hac`` standard deviations. A context's
95 % interval is ``mu +- 1.96 std`` where the data came near the limit
(``mu_lower_bound >= near_limit_fraction x mu``); where they did not, it is the one-sided
``[mu_lower_bound, mu's upper bound]`` (the data do not bound the peak from above; ``--two-sided``
scores ``mu +- 1.96 std`` there too). Coverage is counted over (context, seed) pairs, per group
of seeds (``--calibration-seeds``: the seeds the settings were chosen on; the others are held
out).

``--model-error-rel R`` adds the model-error budget (``FitOptions.model_error_rel``: mu's std
becomes ``sqrt(std^2 + (R mu)^2)``) to both stds. ``--calibrate`` chooses R on the calibration
seeds' two-sided (near-limit) pairs of the first run kind given (``--calibrate-on``, default
``effects``): per pair the smallest R whose ``hac`` interval holds the truth, and R = their
``--target`` quantile (0.9), rounded up to 0.01; then scores every kind with it.
``--calibrate-on live`` chooses R on the runs' own final estimates instead (the live fitter's
mu and its std without the budget the run carried, on the contexts the run flagged near the
limit): the live fitter reads lower than the offline refits where the data are few.

The log is at its logging rate (20 Hz in the shipped scenarios), not the fitter's 100 Hz, so the
refits are close to, not equal to, the live ones (``live`` columns: the run's own final estimate).

Usage: python benchmarks/interval_coverage.py RUN_DIR [RUN_DIR ...] [--calibration-seeds 0-4]
           [--two-sided] [--model-error-rel R | --calibrate [--target 0.9]] [--json-only]
Prints a table per run kind and one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from pcvfe_drake.estimation.effect_fit import EffectFitter, friction_used
from pcvfe_drake.estimation.fit_dataset import build_windows
from pcvfe_drake.estimation.fit_options import MU_BOUNDS, FitOptions, with_model_error
from pcvfe_drake.estimation.fitting import fit_gauss_newton
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.vehicle.single_track import STATE_NAMES

METHODS = ("iid", "hac")
Z95 = 1.959964


def seeds(spec: str) -> set[int]:
    out: set[int] = set()
    for part in filter(None, spec.split(",")):
        lo, _, hi = part.partition("-")
        out.update(range(int(lo), int(hi or lo) + 1))
    return out


def context_rows(log: pd.DataFrame, n_keep: int) -> dict[int, np.ndarray]:
    """Per final-clustering context: its newest ``n_keep`` rows (the live store keeps each
    label's newest ``buffer_s``)."""
    labels = log["final_context"].to_numpy(int)
    return {int(k): np.flatnonzero(labels == k)[-n_keep:] for k in np.unique(labels) if int(k) >= 0}


def fit_context(kind, fitter, t, x, u, fc: dict, dt: float, vehicle, period_s) -> dict | None:
    """mu and its std per method for one buffer (None: too little data)."""
    out = {}
    if kind == "effects":
        for method in METHODS:
            fitter.covariance = method
            res = fitter(t, x, u, None, vehicle.theta[0])
            if res is None:
                return None
            out[method] = (float(res.theta[0]), float(res.std[0]))
            out["rho"] = float(res.loss)
        out["upper"] = float(fitter.model.bounds()[1][0])
        return out
    horizon = max(1, round(fc["horizon_steps"] * period_s / dt))
    stride = max(1, round(fc["stride_steps"] * period_s / dt))
    split = build_windows(t, x, u, horizon=horizon, stride=stride, dt=dt, max_windows=None)
    data = split.by_context.get(0)
    if data is None or data.n_windows < fc["min_windows"]:
        return None
    if data.n_windows > fc["max_windows"]:
        data = data.subset(slice(data.n_windows - fc["max_windows"], None))
    for method in METHODS:
        res = fit_gauss_newton(data, vehicle, None, FitOptions(covariance=method))
        out[method] = (float(res.theta[0]), float(res.std[0]))
        out["rho"] = float(res.quality.get("loss_noise_ratio", math.nan))
    out["upper"] = MU_BOUNDS[1]
    return out


def interval(mu, std, lower_bound, near, upper, two_sided) -> tuple[float, float]:
    if near or two_sided:
        s = std if math.isfinite(std) else math.inf
        return mu - Z95 * s, mu + Z95 * s
    return lower_bound, upper


def synthetic(n_seeds: int, peak: float = 0.7) -> dict:
    """z = (mu_hat - peak) / std of the effect fit (``peak_tyre`` with ``k_s`` 0) on logs of
    that very model (``workbench.synth``: magic-formula tyre, stiffness not following the peak),
    with either std: a calibrated std gives an RMS z of ~1."""
    from pcvfe_drake.workbench.synth import Truth, simulate_truths

    vehicle = load_vehicle("ford_escort")
    z: dict[str, list[float]] = {m: [] for m in METHODS}
    for seed in range(n_seeds):
        log = simulate_truths([Truth(mf_peak=peak)], vehicle, 60.0, 20.0, seed=seed)[0]
        t = log["t"].to_numpy(float)
        x = log[list(STATE_NAMES)].to_numpy(float)
        u = log[["steer_rate", "accel"]].to_numpy(float)
        for method in METHODS:
            res = EffectFitter(vehicle, ["peak_tyre:k_s=0"], covariance=method)(
                t, x, u, None, vehicle.theta[0]
            )
            z[method].append((res.theta[0] - peak) / res.std[0])
        print(f"seed {seed}: " + ", ".join(f"{m} z {z[m][-1]:+.2f}" for m in METHODS))
    return {
        "benchmark": "interval_coverage",
        "synthetic_seeds": n_seeds,
        **{f"z_rms_{m}": float(np.sqrt(np.mean(np.square(z[m])))) for m in METHODS},
        "z": z,
    }


def live_data_std(entry: dict, fc: dict) -> float | None:
    """The live fit's own std of mu: the run's reported std without the model-error budget the
    run carried (``fitter.model_error_rel``); None where the run reported none."""
    std, mu = entry.get("std"), entry.get("mu_hat")
    if std is None or mu is None:
        return None
    rel = float(fc.get("model_error_rel", 0.0) or 0.0)
    return math.sqrt(max(float(std) ** 2 - (rel * float(mu)) ** 2, 0.0))


def needed_rel(fit: dict, true_mu: float) -> float:
    """The smallest model-error budget whose 95 % interval around ``fit`` holds ``true_mu``."""
    gap = (abs(fit["mu"] - true_mu) / Z95) ** 2 - fit["std_data"] ** 2
    return math.sqrt(max(gap, 0.0)) / abs(fit["mu"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "runs",
        nargs="*",
        help="run folders (default: the saved runs of PCVFE_COVERAGE_RUNS, a glob, if set)",
    )
    ap.add_argument("--quick", action="store_true", help="(benchmarks/run_all.py) no effect")
    ap.add_argument("--calibration-seeds", default="0-4")
    ap.add_argument("--two-sided", action="store_true")
    ap.add_argument("--json-only", action="store_true")
    ap.add_argument("--dump", help="write every (context, seed) row to this JSON file")
    ap.add_argument("--model-error-rel", type=float, default=0.0)
    ap.add_argument("--calibrate", action="store_true")
    ap.add_argument("--calibrate-on", default="effects", choices=("effects", "st", "live"))
    ap.add_argument("--target", type=float, default=0.9)
    ap.add_argument(
        "--synthetic",
        type=int,
        default=0,
        metavar="N",
        help="instead: the effect fit's std on its own model's truth (peak_tyre, peak 0.7, "
        "k_s 0; 60 s at 20 Hz), N seeds: z-scores of both stds",
    )
    args = ap.parse_args()
    if args.synthetic:
        print(json.dumps(synthetic(args.synthetic)))
        return
    if not args.runs and os.environ.get("PCVFE_COVERAGE_RUNS"):
        args.runs = sorted(glob.glob(os.environ["PCVFE_COVERAGE_RUNS"]))
    if not args.runs:
        reason = (
            "no run folders given: pass the folders of `pcvfe evaluate` runs (e.g. the "
            "pcvfe_effects experiment's runs/*) or set PCVFE_COVERAGE_RUNS to a glob of them"
        )
        print(f"skipped: {reason}")
        print(json.dumps({"benchmark": "interval_coverage", "skipped": True, "reason": reason}))
        return
    calib = seeds(args.calibration_seeds)
    rows = []
    t_start = time.process_time()
    for folder in sorted(Path(r) for r in args.runs):
        summary = json.loads((folder / "summary.json").read_text())
        scenario = yaml.safe_load((folder / "scenario.yaml").read_text())
        fc = scenario["fitter"]
        fc = {**fc, **fc.get("model", {})}  # the effect model as run (fitter.model)
        period_s = float(scenario.get("rates", {}).get("fitter_sample_period_s", 0.01))
        vehicle = load_vehicle(scenario.get("vehicle"))
        kind = "effects" if fc.get("effects") else "st"
        fitter = None
        if kind == "effects":
            fitter = EffectFitter(
                vehicle,
                fc["effects"],
                horizon_s=fc["effect_horizon_s"],
                stride_s=fc["effect_stride_s"],
                max_windows=fc["effect_max_windows"],
                max_iterations=fc["max_iterations"],
                min_windows=fc["effect_min_windows"],
            )
        log = pd.read_parquet(folder / "drive_log.parquet")
        dt = float(np.median(np.diff(log["t"].to_numpy(float))))
        by_id = {int(c["id"]): c for c in summary["mu_estimates"]}
        buffers = context_rows(log, int(round(fc["buffer_s"] / dt)))
        for k, idx in buffers.items():
            entry = by_id.get(k)
            if entry is None or entry.get("true_mu") is None:
                continue
            t = log["t"].to_numpy(float)[idx]
            x = log[list(STATE_NAMES)].to_numpy(float)[idx]
            u = log[["steer_rate", "accel"]].to_numpy(float)[idx]
            fits = fit_context(kind, fitter, t, x, u, fc, dt, vehicle, period_s)
            if fits is None:
                continue
            used = friction_used(t, x, lateral_only=kind == "effects")
            row = {
                "run": folder.name,
                "kind": kind,
                "seed": int(summary.get("seed", scenario.get("seed", 0))),
                "terrain": entry["majority_terrain"],
                "true_mu": float(entry["true_mu"]),
                "live_mu": entry["mu_hat"],
                "live_std": entry["std"],
                "live_covered": entry["covered_95"],
                "live_near_limit": bool(entry.get("near_limit")),
                "live_std_data": live_data_std(entry, fc),
                "mu_lower_bound": used,
                "rho": fits["rho"],
            }
            for method in METHODS:
                mu, std = fits[method]
                near = bool(math.isfinite(used) and used >= fc["near_limit_fraction"] * mu)
                row[method] = {"mu": mu, "std_data": std, "near_limit": near}
            row["upper"] = fits["upper"]
            rows.append(row)
    cpu = time.process_time() - t_start
    rel = args.model_error_rel
    result = {
        "benchmark": "interval_coverage",
        "two_sided": args.two_sided,
        "calibration_seeds": sorted(calib),
        "cpu_s": cpu,
    }
    if args.calibrate:
        if args.calibrate_on == "live":
            need = sorted(
                needed_rel({"mu": r["live_mu"], "std_data": r["live_std_data"]}, r["true_mu"])
                for r in rows
                if r["seed"] in calib and r["live_near_limit"] and r["live_std_data"] is not None
            )
        else:
            need = sorted(
                needed_rel(r["hac"], r["true_mu"])
                for r in rows
                if r["kind"] == args.calibrate_on and r["seed"] in calib and r["hac"]["near_limit"]
            )
        if not need:
            raise SystemExit(f"--calibrate: no near-limit {args.calibrate_on} pairs to calibrate")
        q = need[min(len(need) - 1, math.ceil(args.target * len(need)) - 1)]
        rel = math.ceil(q * 100 - 1e-9) / 100
        result["calibration"] = {
            "on": args.calibrate_on,
            "pairs": len(need),
            "needed_rel": need,
            "target": args.target,
            "model_error_rel": rel,
        }
        if not args.json_only:
            print(
                f"calibrated on {len(need)} near-limit {args.calibrate_on} pairs of seeds "
                f"{args.calibration_seeds}: needed {', '.join(f'{v:.3f}' for v in need)}; "
                f"model_error_rel = {rel:.2f}"
            )
    result["model_error_rel"] = rel
    for row in rows:
        for method in METHODS:
            c = row[method]
            c["std"] = with_model_error(c["mu"], c["std_data"], rel)
            bound, near = row["mu_lower_bound"], c["near_limit"]
            lo, hi = interval(c["mu"], c["std"], bound, near, row["upper"], args.two_sided)
            c["interval"] = [lo, hi]
            c["covered"] = bool(lo <= row["true_mu"] <= hi)
    for kind in sorted({r["kind"] for r in rows}):
        sel = [r for r in rows if r["kind"] == kind]
        res_k = {}
        if not args.json_only:
            print(f"\n{kind}: {len(sel)} (context, seed) pairs")
            print(
                f"{'seed':>4} {'terrain':>13} {'mu':>5} | {'live':>13} | "
                + " | ".join(f"{m:>22}" for m in METHODS)
            )
            for r in sel:
                cells = []
                for m in METHODS:
                    c = r[m]
                    cells.append(
                        f"{c['mu']:6.3f} +-{c['std']:6.3f}{'' if c['near_limit'] else ' n'}"
                        f" {'Y' if c['covered'] else '-'}"
                    )
                live = (
                    f"{r['live_mu']:5.3f}+-{r['live_std']:5.3f}"
                    if r["live_std"] is not None
                    else f"{r['live_mu']:5.3f}"
                )
                print(
                    f"{r['seed']:>4} {r['terrain']:>13} {r['true_mu']:5.2f} | {live:>13} | "
                    + " | ".join(f"{c:>22}" for c in cells)
                )
        for group, pick in (
            ("calibration", lambda r: r["seed"] in calib),
            ("held_out", lambda r: r["seed"] not in calib),
            ("all", lambda r: True),
        ):
            g = [r for r in sel if pick(r)]
            res_k[group] = {
                "pairs": len(g),
                "live_covered": sum(bool(r["live_covered"]) for r in g),
                **{
                    m: {
                        "covered": sum(r[m]["covered"] for r in g),
                        "two_sided_pairs": sum(r[m]["near_limit"] for r in g),
                        "two_sided_covered": sum(r[m]["covered"] for r in g if r[m]["near_limit"]),
                    }
                    for m in METHODS
                },
            }
        result[kind] = res_k
        if not args.json_only:
            for group, v in res_k.items():
                print(
                    f"  {group:>11}: {v['pairs']} pairs, live {v['live_covered']}; "
                    + "; ".join(
                        f"{m} {v[m]['covered']} (two-sided {v[m]['two_sided_covered']}/"
                        f"{v[m]['two_sided_pairs']})"
                        for m in METHODS
                    )
                )
    if args.dump:
        Path(args.dump).write_text(json.dumps(rows))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
