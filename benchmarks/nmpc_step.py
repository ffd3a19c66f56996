"""Time one full NMPC update (linearise + assemble + solve) against a naive dense rebuild.

The controller drives the Ford Escort around the ``slalom`` course (ST truth, mu 0.6) at the
default horizon (40 x 0.05 s). At every update, on the same measured state and the same memory:

- ``rti_sparse``: ``NmpcController.step``: batched Jacobians and exact discretisation, values
  written into the fixed CSC patterns, ``osqp.update`` + warm start + solve (the real update,
  whose result drives the car);
- ``naive_dense``: the same linearisation, then the QP built densely term by term
  (``reference_qp.dense_qp``), converted to CSC, and a fresh ``osqp.OSQP().setup`` + solve (same
  settings, no warm start) every step.

Both wall-clock (``perf_counter``) and thread CPU time (``thread_time``) are reported; on a
shared machine the CPU time is the steadier measure. The ratio is naive / sparse median.

Usage: ``python benchmarks/nmpc_step.py [--quick]``; the last stdout line is a JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import osqp
import scipy.sparse as sp

from pcvfe_drake.control.closed_loop import StTruth
from pcvfe_drake.control.course import initial_state, load_course
from pcvfe_drake.control.nmpc import NmpcConfig, NmpcController
from pcvfe_drake.control.reference_qp import dense_qp
from pcvfe_drake.vehicle.params import ford_escort


def stats(values) -> dict:
    a = np.asarray(values) * 1e3
    return {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95))}


def naive_update(ctrl: NmpcController, x, theta, memory) -> str:
    prof = ctrl.profile(theta[0])
    lin = ctrl.linearize(x, theta, memory, prof)
    P, q, A, lo, hi = dense_qp(ctrl, lin)
    solver = osqp.OSQP()
    solver.setup(sp.csc_matrix(np.triu(P)), q, sp.csc_matrix(A), lo, hi, **ctrl.osqp_settings())
    return str(solver.solve(raise_error=False).info.status)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="100 updates instead of 400")
    args = ap.parse_args(argv)
    updates = 100 if args.quick else 400

    params = ford_escort()
    course = load_course("slalom")
    ctrl = NmpcController(course, params, NmpcConfig())
    theta = np.array([0.6, params.C_Sf, params.C_Sr])
    plant = StTruth(params)
    x = plant.reset(initial_state(course, params, 5.0))
    every = int(round(ctrl.config.dt_s / 0.01))

    rows = {"rti_sparse": ([], []), "naive_dense": ([], []), "linearize": ([], [])}
    assemble, solve, iters, statuses, naive_status = [], [], [], [], []
    for k in range(updates):
        memory = ctrl.memory
        # Component timings of the sparse path on the same inputs (not used for control).
        t0 = time.perf_counter()
        lin = ctrl.linearize(x, theta, memory, ctrl.profile(theta[0]))
        t1 = time.perf_counter()
        ctrl.qp_vectors(lin)
        t2 = time.perf_counter()
        rows["linearize"][0].append(t1 - t0)
        assemble.append(t2 - t1)
        # Naive dense rebuild on the same inputs.
        w0, c0 = time.perf_counter(), time.thread_time()
        naive_status.append(naive_update(ctrl, x, theta, memory))
        rows["naive_dense"][0].append(time.perf_counter() - w0)
        rows["naive_dense"][1].append(time.thread_time() - c0)
        # The real update (drives the car).
        w0, c0 = time.perf_counter(), time.thread_time()
        u = ctrl.update(x, theta)
        rows["rti_sparse"][0].append(time.perf_counter() - w0)
        rows["rti_sparse"][1].append(time.thread_time() - c0)
        d = ctrl.last_diagnostics
        solve.append(d.solve_time_s)
        iters.append(d.iterations)
        statuses.append(d.mode)
        for _ in range(every):
            x = plant.step(u, theta[0], 0.01)
        if k % 50 == 0:
            print(
                f"update {k:4d}: sparse {rows['rti_sparse'][0][-1] * 1e3:6.2f} ms, "
                f"naive {rows['naive_dense'][0][-1] * 1e3:7.2f} ms, "
                f"lateral error {d.lateral_error_m * 100:5.1f} cm",
                flush=True,
            )

    sparse_wall = stats(rows["rti_sparse"][0])
    naive_wall = stats(rows["naive_dense"][0])
    sparse_cpu = stats(rows["rti_sparse"][1])
    naive_cpu = stats(rows["naive_dense"][1])
    lay = ctrl.layout
    result = {
        "benchmark": "nmpc_step",
        "quick": args.quick,
        "updates": updates,
        "horizon_steps": ctrl.N,
        "dt_s": ctrl.config.dt_s,
        "qp_variables": lay.nz,
        "qp_constraints": lay.m,
        "nnz_P": ctrl._P.size,
        "nnz_A": ctrl._A.size,
        "rti_sparse_wall": sparse_wall,
        "rti_sparse_cpu": sparse_cpu,
        "naive_dense_wall": naive_wall,
        "naive_dense_cpu": naive_cpu,
        "speedup_median_wall": naive_wall["median_ms"] / sparse_wall["median_ms"],
        "speedup_median_cpu": naive_cpu["median_ms"] / sparse_cpu["median_ms"],
        "sparse_breakdown_median_ms": {
            "linearize": float(np.median(rows["linearize"][0]) * 1e3),
            "assemble": float(np.median(assemble) * 1e3),
            "osqp_solve": float(np.median(solve) * 1e3),
        },
        "osqp_iterations_median": float(np.median(iters)),
        "fallbacks": int(sum(m != "qp" for m in statuses)),
        "naive_unsolved": int(sum(s != "solved" for s in naive_status)),
        "target_median_ms": 5.0,
        "meets_target_cpu": sparse_cpu["median_ms"] <= 5.0,
    }
    print(
        f"sparse RTI: median {sparse_wall['median_ms']:.2f} ms wall / "
        f"{sparse_cpu['median_ms']:.2f} ms CPU, p95 {sparse_wall['p95_ms']:.2f} ms wall; "
        f"naive dense: median {naive_wall['median_ms']:.2f} ms wall / "
        f"{naive_cpu['median_ms']:.2f} ms CPU; speedup x{result['speedup_median_wall']:.1f}"
    )
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
