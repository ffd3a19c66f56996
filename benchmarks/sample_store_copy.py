"""What the fitter's labelled sample store costs per Drake update, and per relabelling.

Drake copies the ContextFitter's abstract state (the ``ContextEstimator``) at every unrestricted
update (100 Hz). The store shares its full chunks between copies, so a copy should cost the same
with a few seconds of data as with the full budget (5 contexts + noise, 60 s each at 100 Hz).
Measured: ``copy.deepcopy`` of the estimator (median of repeated copies) with a small and a full
store, their ratio, the store's memory, and the time of one relabelling (all samples mapped to
a re-clustering's frames) of the full store.

Usage: python benchmarks/sample_store_copy.py [--quick]
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import time

import numpy as np

from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.vehicle.params import ford_escort


def filled(n_samples: int) -> ContextEstimator:
    """Five terrains, one after the other, the first 1/12 of each reported as noise."""
    est = ContextEstimator(ford_escort(), LiveFitConfig())
    state = np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    span = n_samples // 5
    for k in range(n_samples):
        ident = k // span
        est.add_sample(0.01 * k, state, [0.0, 0.0], [ident if k % span >= span // 12 else -1])
    return est


def copy_time_us(est: ContextEstimator, reps: int) -> float:
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        copy.deepcopy(est)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = parser.parse_args()
    reps = 200 if args.quick else 2000
    small, full = filled(1_000), filled(36_000)
    rows = len(full._store)
    t_small, t_full = copy_time_us(small, reps), copy_time_us(full, reps)
    frame_t = np.round(np.arange(0.0, 360.0, 0.1), 6)[-2000:]  # the clusterer's 2000 frames
    frame_l = (frame_t // 72).astype(int)  # the 5 terrains' 72 s spans
    t0 = time.perf_counter()
    moved = full.relabel(frame_t, frame_l, 0.1, version=1)
    relabel_ms = (time.perf_counter() - t0) * 1e3
    result = {
        "rows_small": len(small._store),
        "rows_full": rows,
        "store_mb_full": round(rows * (1 + 7 + 2 + 1) * 8 / 1e6, 2),
        "copy_us_small": round(t_small, 1),
        "copy_us_full": round(t_full, 1),
        "copy_ratio_full_over_small": round(t_full / t_small, 2),
        "relabel_ms_full": round(relabel_ms, 2),
        "relabelled_samples": int(sum(v for v in moved.values() if v > 0)),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
