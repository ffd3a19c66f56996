"""``pcvfe diagnose`` speed: a 240 s drive log at 50 Hz, the loop over the whole library.

The log comes from ``pcvfe_drake.workbench.synth`` (planted aerodynamic drag and input delay,
GNSS/INS noise). The full diagnosis is timed: baseline fit, the forward selection (every
library effect fitted and evaluated on held-out data in every round, on top of the effects
found so far), the backward checks, the verdict's tests and the residual analysis. The target
is <= 60 s on a 2-core machine.

Baseline for the ratio (same run, same data): the straightforward way to evaluate a model on
many windows is one rollout per window in a Python loop. ``vectorised_speedup`` is the time of
that loop over all training windows divided by the time of the vectorised multi-window rollout
the workbench uses (both the drag model at the same parameters; results agree to 1e-12).

Times are CPU time of the process (``time.process_time``; robust when other jobs share the
machine) and wall clock.

Usage: python benchmarks/diagnose_speed.py [--quick]   (--quick: 120 s log)
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from pcvfe_drake.models.data import prepare
from pcvfe_drake.models.effects import known_effects
from pcvfe_drake.workbench import synth
from pcvfe_drake.workbench.report import diagnose


def _timed(fn):
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c0, time.perf_counter() - w0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="120 s log instead of 240 s")
    parser.add_argument("--duration", type=float, default=None, help="log length [s]")
    parser.add_argument("--rate", type=float, default=50.0, help="sample rate [Hz]")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    duration = args.duration or (120.0 if args.quick else 240.0)

    print(f"simulating a {duration:g} s log at {args.rate:g} Hz (drag + delay) ...", flush=True)
    (df,), _, sim_wall = _timed(
        lambda: synth.simulate_truths(
            [synth.Truth(CdA=0.75, accel_delay=0.17)],
            duration_s=duration,
            rate_hz=args.rate,
            seed=args.seed,
            substeps=2,
        )
    )
    data = prepare(df, f"synthetic {duration:g} s")
    print(f"  {len(df)} rows in {sim_wall:.1f} s; diagnosing ...", flush=True)
    (report, wb), cpu, wall = _timed(lambda: diagnose(data))
    print(f"  diagnose: {cpu:.1f} s CPU, {wall:.1f} s wall; verdict: {report['verdict']['text']}")

    # vectorised multi-window rollout vs one rollout per window
    model = wb.base_model.with_effects("drag")
    theta = model.initial_theta()
    theta[-1] = 0.75
    starts = wb.train_starts
    h = wb.h_fit
    (z_vec), cpu_vec, _ = _timed(lambda: model.simulate(theta, data, starts, h))
    z_loop, cpu_loop, _ = _timed(
        lambda: np.concatenate(
            [model.simulate(theta, data, starts[i : i + 1], h) for i in range(starts.size)]
        )
    )
    agree = float(np.max(np.abs(z_vec - z_loop)))
    speedup = cpu_loop / max(cpu_vec, 1e-9)
    print(
        f"  {starts.size} windows x {h} steps: vectorised {cpu_vec * 1e3:.1f} ms, "
        f"per-window loop {cpu_loop * 1e3:.1f} ms ({speedup:.1f}x), max difference {agree:.1e}"
    )
    result = {
        "benchmark": "diagnose_speed",
        "log_s": duration,
        "rate_hz": args.rate,
        "rows": len(df),
        "effects_ranked": len(report["ranked_effects"]),
        "library": known_effects(),
        "diagnose_cpu_s": round(cpu, 3),
        "diagnose_wall_s": round(wall, 3),
        "target_s": 60.0,
        "within_target": bool(cpu <= 60.0),
        "selected": [x["name"] for x in report["selected"]],
        "fits": wb.n_fits,
        "verdict": report["verdict"]["kind"],
        "training_windows": int(starts.size),
        "heldout_windows": int(wb.eval_starts.size),
        "vectorised_rollout_cpu_s": round(cpu_vec, 4),
        "per_window_loop_cpu_s": round(cpu_loop, 4),
        "vectorised_speedup": round(speedup, 2),
        "max_abs_difference": agree,
        "cpus": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
