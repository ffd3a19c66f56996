"""CPU per online refit of one context: the single-track fit against the effect-model fit.

The ``ContextFitter`` refits up to 2 contexts per 1 s update, each warm-started on its buffer
(60 s at 100 Hz). This drives a ``ContextEstimator`` through ``--seconds`` of a synthetic
saturating-tyre drive (``workbench.synth``, brush tyre, stiffness mu 0.8, peak 0.7, survey-grade
noise), one 1 s update at a time, once with the ST fit (default ``fitter``) and once per effect
list given (``fitter.effects``), and reports the CPU time per refit (median and 95th percentile,
``time.process_time``) and the ratio to the ST fit, measured in the same run; each effect list
is driven twice, with incremental refits (``incremental_fit``, the default) and with the batch
fit at every refit (``effect_incremental: false``), and the speed-up and the difference of the
final mu in units of the batch fit's std are reported. It also times the
standard deviations' step alone (``covariance_cpu_s``): the ``hac`` sandwich
(``least_squares.hac_covariance``) and the Gauss-Newton ``least_squares.covariance`` on a
Jacobian of each fit's live size (ST: 512 windows x 10 steps x 7 states, lag 42 windows; effect
model: 100 windows x 15 steps x 5 states, 2 parameters, lag 6).

Usage: python benchmarks/context_refit_speed.py [--quick] [--seconds 90]
           [--effects tire_saturation ...]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.sample_store import inputs_as_read
from pcvfe_drake.models.effect_model import EffectModel
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth

STATES = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]


def drive(est: ContextEstimator, t, S, U) -> dict:
    cpu = []
    last = t[0]
    read = inputs_as_read(U)  # what a sample reads: the input applied before it
    for k in range(t.size):
        est.add_sample(t[k], S[k], read[k], 0)
        if t[k] - last >= 1.0 - 1e-9:
            last = t[k]
            c0 = time.process_time()
            est.refit(float(t[k]))
            cpu.append(time.process_time() - c0)
    entry = est.table().get(0)
    cpu = np.array(cpu[10:])  # from 10 s on (the first seconds have too little data)
    return {
        "refits": int(cpu.size),
        "cpu_median_s": float(np.median(cpu)),
        "cpu_p95_s": float(np.quantile(cpu, 0.95)),
        "cpu_max_s": float(np.max(cpu)),
        "mu": entry.mu,
        "mu_std": entry.mu_std,
        "mu_lower_bound": entry.mu_lower_bound,
        "model_params": {n: v for n, v, _ in entry.model_params},
    }


def covariance_cost(repeats: int = 50) -> dict:
    """CPU per call of the sandwich and of the Gauss-Newton covariance on live-size Jacobians."""
    from pcvfe_drake.models import least_squares as lsq

    rng = np.random.default_rng(0)
    out = {}
    for name, (windows, rows, p, lag) in {
        "single_track": (512, 70, 1, 42),
        "effects": (100, 75, 2, 6),
    }.items():
        J = rng.normal(size=(windows * rows, p))
        r = rng.normal(size=windows * rows)
        timing = {}
        for label, call in (
            ("hac", lambda J=J, r=r, w=windows, lag=lag: lsq.hac_covariance(J, r, w, lag)),
            ("gauss_newton", lambda J=J, r=r: lsq.covariance(J, float(r @ r))),
        ):
            c0 = time.process_time()
            for _ in range(repeats):
                call()
            timing[label] = (time.process_time() - c0) / repeats
        out[name] = timing
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=90.0)
    parser.add_argument("--quick", action="store_true", help="30 s of driving (run_all --quick)")
    parser.add_argument(
        "--effects", nargs="*", default=["tire_saturation"], help="effect lists, ';'-separated"
    )
    args = parser.parse_args()
    if args.quick:
        args.seconds = min(args.seconds, 30.0)
    vp = ford_escort()
    truth = synth.Truth(mu=0.8, mu_peak=0.7)
    print(f"simulating {args.seconds:g} s of the synthetic drive at 100 Hz", flush=True)
    df = synth.simulate_truths([truth], vp, duration_s=args.seconds, rate_hz=100.0, seed=0)[0]
    t = df["t"].to_numpy()
    S = df[STATES].to_numpy()
    U = df[["steer_rate", "accel"]].to_numpy()
    st = drive(ContextEstimator(vp, LiveFitConfig()), t, S, U)
    print(f"single-track: {st}", flush=True)
    runs = {}
    for spec in args.effects:
        effects = [e for e in spec.split(";") if e]
        res = drive(
            ContextEstimator(vp, LiveFitConfig(model=EffectModel(effects=effects))), t, S, U
        )
        res["cpu_ratio_vs_st"] = res["cpu_median_s"] / st["cpu_median_s"]
        print(f"{spec} (incremental): {res}", flush=True)
        batch_config = LiveFitConfig(model=EffectModel(effects=effects), effect_incremental=False)
        batch = drive(ContextEstimator(vp, batch_config), t, S, U)
        res["batch"] = batch
        res["speedup_vs_batch"] = batch["cpu_median_s"] / res["cpu_median_s"]
        res["mu_minus_batch_in_std"] = (res["mu"] - batch["mu"]) / batch["mu_std"]
        runs[spec] = res
        print(f"{spec} (batch): {batch}", flush=True)
    cov = covariance_cost()
    print(f"covariance step alone (CPU per call): {cov}", flush=True)
    print(
        json.dumps(
            {
                "benchmark": "context_refit_speed",
                "seconds": args.seconds,
                "truth": {"mu": 0.8, "mu_peak": 0.7},
                "single_track": st,
                "effects": runs,
                "covariance_cpu_s": cov,
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
