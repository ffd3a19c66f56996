"""The NMPC's batched matrix exponential against SciPy's, on the matrices of real updates.

Every NMPC update discretises the linearised dynamics over the horizon with one batch of matrix
exponentials of the augmented matrices ``[[A, B, f], [0, 0, 0]] dt`` (40 matrices of 10 x 10 at
the default horizon; ``pcvfe_drake.control.prediction_model.discretize``). This benchmark drives
the Ford Escort on the ``slalom`` course (ST truth, true mu 0.6 given, from 5 m/s) with the
controller, keeps the batches of every update, and times on each batch:

- ``expm_batched``: the project's scaling-and-squaring Taylor-12 exponential, vectorised over
  the batch (what the controller uses);
- ``scipy``: ``scipy.linalg.expm`` on the same (B, n, n) array (SciPy handles the batch itself),
  with the BLAS threads as they are and again limited to one thread (``threadpoolctl``): on a
  loaded machine a threaded BLAS call on 10 x 10 matrices can stall for tens to hundreds of ms.

Both are timed back to back on each batch (best of ``--repeats`` calls each); the median and
95th percentile over the batches and the ratio of the summed times are reported, with the
largest relative difference between the two results. The controller keeps
whichever is faster: the decision and its figures are in ``docs/nmpc.md``.

Usage: ``python benchmarks/nmpc_expm.py [--quick]``; the last stdout line is a JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
import scipy
import scipy.linalg
from threadpoolctl import threadpool_limits

import pcvfe_drake.control.prediction_model as prediction_model
from pcvfe_drake.control.closed_loop import simulate_closed_loop
from pcvfe_drake.control.course import initial_state, load_course
from pcvfe_drake.control.nmpc import NmpcConfig, NmpcController
from pcvfe_drake.vehicle.params import ford_escort


def captured_batches(duration_s: float) -> list[np.ndarray]:
    """The augmented matrices of every NMPC update of a closed loop of ``duration_s``."""
    batches: list[np.ndarray] = []
    original = prediction_model.expm_batched

    def keep(m: np.ndarray) -> np.ndarray:
        batches.append(m.copy())
        return original(m)

    params = ford_escort()
    course = load_course("slalom")
    ctrl = NmpcController(course, params, NmpcConfig())
    prediction_model.expm_batched = keep
    try:
        simulate_closed_loop(
            ctrl, initial_state(course, params, 5.0, 20.0), duration_s, mu_at=lambda xy: 0.6
        )
    finally:
        prediction_model.expm_batched = original
    return batches


def best_time(fn, m: np.ndarray, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn(m)
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="2 s of driving instead of 10 s")
    parser.add_argument("--repeats", type=int, default=5, help="calls per batch and method")
    args = parser.parse_args(argv)

    batches = captured_batches(2.0 if args.quick else 10.0)
    ours, theirs, single, rel = [], [], [], []
    for m in batches:
        ours.append(best_time(prediction_model.expm_batched, m, args.repeats))
        theirs.append(best_time(scipy.linalg.expm, m, args.repeats))
        with threadpool_limits(limits=1, user_api="blas"):
            single.append(best_time(scipy.linalg.expm, m, args.repeats))
        a, b = prediction_model.expm_batched(m), scipy.linalg.expm(m)
        rel.append(float(np.abs(a - b).max() / np.abs(b).max()))

    def stats(times: list[float]) -> dict:
        us = np.asarray(times) * 1e6
        return {
            "median_us": float(np.median(us)),
            "p95_us": float(np.percentile(us, 95)),
            "max_us": float(us.max()),
            "total_s": float(us.sum() * 1e-6),
        }

    rows = {
        "expm_batched": stats(ours),
        "scipy": stats(theirs),
        "scipy_one_blas_thread": stats(single),
    }
    for name, row in rows.items():
        print(
            f"{name:>22}: median {row['median_us']:.0f} us, p95 {row['p95_us']:.0f} us, "
            f"max {row['max_us']:.0f} us, total {row['total_s']:.3f} s"
        )
    print(f"{len(batches)} batches of {batches[0].shape}; max relative difference {max(rel):.1e}")
    base = rows["expm_batched"]["median_us"]
    result = {
        "batches": len(batches),
        "batch_shape": list(batches[0].shape),
        **{f"{name}_{key}": value for name, row in rows.items() for key, value in row.items()},
        "scipy_over_expm_batched_median_ratio": rows["scipy"]["median_us"] / base,
        "scipy_one_thread_over_expm_batched_median_ratio": (
            rows["scipy_one_blas_thread"]["median_us"] / base
        ),
        "max_relative_difference": max(rel),
        "scipy_version": scipy.__version__,
        "load_average_1min": os.getloadavg()[0],
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
