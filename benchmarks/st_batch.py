"""Benchmark: vectorised ST dynamics and Jacobians for 100k states vs a Python loop over
CommonRoad's ``vehicle_dynamics_st``.

Baselines (measured in the same run, on a subset of the states and scaled to the full count):
  * dynamics: one ``vehicle_dynamics_st`` call per state;
  * Jacobians: forward differences in the same loop (1 + 7 + 2 calls per state for A and B; the
    package cannot perturb mu, C_Sf, C_Sr separately, so P is not in the baseline although the
    vectorised side computes it too).

Usage: python benchmarks/st_batch.py [--quick]   (last stdout line: one JSON object)
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from vehiclemodels.parameters_vehicle1 import parameters_vehicle1
from vehiclemodels.vehicle_dynamics_st import vehicle_dynamics_st

from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import st_dynamics, st_jacobians


def random_batch(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """States in the dynamic range (v in [1, 30] m/s) and inputs inside the limits."""
    x = np.column_stack(
        [
            rng.uniform(-100, 100, n),
            rng.uniform(-100, 100, n),
            rng.uniform(-0.5, 0.5, n),
            rng.uniform(1.0, 30.0, n),
            rng.uniform(-np.pi, np.pi, n),
            rng.uniform(-1.0, 1.0, n),
            rng.uniform(-0.2, 0.2, n),
        ]
    )
    u = np.column_stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-5.0, 5.0, n)])
    return x, u


def best_of(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def chunked(fn, x: np.ndarray, u: np.ndarray, params: VehicleParams, block: int) -> None:
    for i in range(0, x.shape[0], block):
        fn(x[i : i + block], u[i : i + block], params)


def loop_dynamics(x: np.ndarray, u: np.ndarray, p) -> np.ndarray:
    return np.array(
        [vehicle_dynamics_st(xi, ui, p) for xi, ui in zip(x.tolist(), u.tolist(), strict=True)]
    )


def loop_fd_jacobians(x: np.ndarray, u: np.ndarray, p, h: float = 1e-6) -> None:
    for xi, ui in zip(x.tolist(), u.tolist(), strict=True):
        f0 = np.array(vehicle_dynamics_st(xi, ui, p))
        a = np.empty((7, 7))
        b = np.empty((7, 2))
        for j in range(7):
            xp = list(xi)
            xp[j] += h
            a[:, j] = (np.array(vehicle_dynamics_st(xp, ui, p)) - f0) / h
        for j in range(2):
            up = list(ui)
            up[j] += h
            b[:, j] = (np.array(vehicle_dynamics_st(xi, up, p)) - f0) / h


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller baseline subset")
    args = parser.parse_args()

    n = 100_000
    n_loop = 2_000 if args.quick else 10_000
    n_fd = 500 if args.quick else 2_000
    repeats = 2 if args.quick else 3
    rng = np.random.default_rng(0)
    p_cr = parameters_vehicle1()
    params = VehicleParams.from_commonroad(p_cr, name="ford_escort")
    x, u = random_batch(n, rng)

    print(f"vectorised st_dynamics on {n} states ...", flush=True)
    t_dyn = best_of(lambda: st_dynamics(x, u, params), repeats)
    print(f"  {t_dyn * 1e3:.1f} ms", flush=True)
    print(f"vectorised st_jacobians (A, B, P) on {n} states ...", flush=True)
    t_jac = best_of(lambda: st_jacobians(x, u, params), repeats)
    print(f"  {t_jac * 1e3:.1f} ms", flush=True)

    block = 4096
    print(f"  the same in blocks of {block} states (temporaries stay in cache) ...", flush=True)
    t_dyn_blk = best_of(lambda: chunked(st_dynamics, x, u, params, block), repeats)
    t_jac_blk = best_of(lambda: chunked(st_jacobians, x, u, params, block), repeats)
    print(f"  dynamics {t_dyn_blk * 1e3:.1f} ms, Jacobians {t_jac_blk * 1e3:.1f} ms", flush=True)

    print(f"Python loop over vehicle_dynamics_st on {n_loop} states ...", flush=True)
    t0 = time.perf_counter()
    f_loop = loop_dynamics(x[:n_loop], u[:n_loop], p_cr)
    t_loop = (time.perf_counter() - t0) * n / n_loop
    print(f"  {t_loop:.2f} s scaled to {n}", flush=True)
    print(f"Python loop of forward-difference A, B on {n_fd} states ...", flush=True)
    t0 = time.perf_counter()
    loop_fd_jacobians(x[:n_fd], u[:n_fd], p_cr)
    t_fd = (time.perf_counter() - t0) * n / n_fd
    print(f"  {t_fd:.2f} s scaled to {n}", flush=True)

    f_vec = st_dynamics(x[:n_loop], u[:n_loop], params)
    rel_err = float(np.max(np.abs(f_vec - f_loop) / (np.abs(f_loop) + 1e-9)))
    result = {
        "benchmark": "st_batch",
        "quick": args.quick,
        "states": n,
        "vectorised_dynamics_s": round(t_dyn, 5),
        "vectorised_jacobians_s": round(t_jac, 5),
        "loop_dynamics_s": round(t_loop, 3),
        "loop_fd_jacobians_s": round(t_fd, 3),
        "loop_subset_states": n_loop,
        "fd_subset_states": n_fd,
        "speedup_dynamics": round(t_loop / t_dyn, 1),
        "speedup_jacobians": round(t_fd / t_jac, 1),
        "vectorised_dynamics_blocks_s": round(t_dyn_blk, 5),
        "vectorised_jacobians_blocks_s": round(t_jac_blk, 5),
        "speedup_dynamics_blocks": round(t_loop / t_dyn_blk, 1),
        "speedup_jacobians_blocks": round(t_fd / t_jac_blk, 1),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "max_rel_err_vs_commonroad": rel_err,
        "target_speedup": 50,
    }
    print(
        f"dynamics: {result['speedup_dynamics']}x ({result['speedup_dynamics_blocks']}x in "
        f"blocks), Jacobians: {result['speedup_jacobians']}x "
        f"({result['speedup_jacobians_blocks']}x in blocks) (target >= 50x); "
        f"max relative difference to CommonRoad {rel_err:.1e}"
    )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
