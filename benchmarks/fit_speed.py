"""Friction fitting: the default bounded Gauss-Newton vs the paper's Adam, same data, same loss.

Data: an S-curve drive of the ST model at ~8 m/s on concrete (mu 0.6, Ford Escort), sampled at
100 Hz with the documented measurement noise
(``pcvfe_drake.models.synthetic_drive.MeasurementNoise``),
cut into windows of H = 10 steps every 5 samples; the first 1024 windows are used (about 51 s of
driving). Both solvers fit mu from the vehicle's nominal value (1.0489) with the stiffnesses held.

* Gauss-Newton (``fit_gauss_newton``, default options): timed over ``--repeats`` cold starts
  (median).
* Adam (``fit_adam``: learning rate 0.01, batch 1024 = all windows, exact gradients through the
  rollout): run until its loss is at or below the Gauss-Newton loss (to a relative rounding
  tolerance of 1e-9: "the same or lower loss") or ``--adam-cap`` steps. The time it first came
  within 1e-6 of the Gauss-Newton loss is reported too (Adam overshoots and crosses the optimum,
  so it touches that band early and leaves it again), and the time from which it stayed there.

Times are CPU time of the process (``time.process_time``; robust when other jobs share the
machine) and wall clock. ``speedup`` = Adam CPU time to reach the Gauss-Newton loss / Gauss-Newton
CPU time; ``work_ratio`` compares rollouts with sensitivities (full-dataset equivalents), which
does not depend on the machine. If Adam does not reach the loss within the cap, ``adam.reached``
is false and the ratios are lower bounds.

Usage: python benchmarks/fit_speed.py [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from pcvfe_drake.estimation.fit_dataset import build_windows
from pcvfe_drake.estimation.fitting import fit_adam, fit_gauss_newton
from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort

SAME_LOSS_RTOL = 1e-9
NEAR_LOSS_RTOL = 1e-6


def scipy_fit(data, params, repeats: int) -> dict:
    """The same problem (mu only, same loss and bounds, from the nominal mu) solved by
    ``scipy.optimize.least_squares`` (trust-region reflective, exact Jacobian from the rollout
    sensitivities, x_scale = the start): the candidate for the shared least-squares core."""
    from scipy.optimize import least_squares

    from pcvfe_drake.estimation.fit_loss import window_residuals
    from pcvfe_drake.estimation.fit_options import FitOptions

    options = FitOptions()
    lower, upper = options.bounds(params)
    weights = options.weights
    cache: dict = {}

    def both(mu):
        key = float(mu[0])
        if key not in cache:
            theta = np.array([key, *params.theta[1:]])
            R, J = window_residuals(theta, data, params, weights, True, options.max_step_s)
            cache.clear()
            cache[key] = (R.reshape(-1), J.reshape(-1, J.shape[-1])[:, :1])
        return cache[key]

    cpu, out = [], None
    for _ in range(repeats):
        cache.clear()
        c0 = time.process_time()
        out = least_squares(
            lambda m: both(m)[0],
            [params.theta[0]],
            jac=lambda m: both(m)[1],
            bounds=(lower[:1], upper[:1]),
            method="trf",
            x_scale=[params.theta[0]],
            xtol=1e-7,
            ftol=1e-9,
        )
        cpu.append(time.process_time() - c0)
    count = data.n_windows * data.horizon
    return {
        "cpu_s": float(np.median(cpu)),
        "mu": float(out.x[0]),
        "loss": float(2.0 * out.cost / count),
        "nfev": int(out.nfev),
        "njev": int(out.njev),
        "status": int(out.status),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="256 windows, Adam cap 400 steps")
    parser.add_argument("--windows", type=int, default=None, help="windows (default 1024)")
    parser.add_argument("--horizon", type=int, default=10, help="H [steps]")
    parser.add_argument("--stride", type=int, default=5, help="window stride [samples]")
    parser.add_argument("--mu", type=float, default=0.6, help="true friction coefficient")
    parser.add_argument("--adam-cap", type=int, default=None, help="Adam step cap (default 1500)")
    parser.add_argument("--repeats", type=int, default=3, help="Gauss-Newton timing repeats")
    parser.add_argument("--noise-free", action="store_true", help="no measurement noise")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    n_windows = args.windows or (256 if args.quick else 1024)
    adam_cap = args.adam_cap or (400 if args.quick else 1500)
    dt = 0.01

    params = ford_escort()
    duration = (n_windows * args.stride + args.horizon + 20) * dt
    print(f"simulating {duration:.1f} s of S-curve driving (mu {args.mu})", flush=True)
    t, S, U = s_curve_drive(params, [args.mu], duration_s=duration, dt=dt)
    states = S[0]
    if not args.noise_free:
        states = MeasurementNoise().apply(states, np.random.default_rng(args.seed))
    data = build_windows(t, states, U[0], horizon=args.horizon, stride=args.stride)
    data = data.by_context[0].subset(slice(0, n_windows))
    if data.n_windows < n_windows:
        raise SystemExit(f"only {data.n_windows} windows built, wanted {n_windows}")
    print(f"{data.n_windows} windows, H = {data.horizon}, dt = {data.dt} s", flush=True)

    gn_cpu, gn_wall = [], []
    for i in range(args.repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        gn = fit_gauss_newton(data, params)
        gn_cpu.append(time.process_time() - c0)
        gn_wall.append(time.perf_counter() - w0)
        print(
            f"gauss-newton run {i + 1}: mu {gn.mu:.6f} loss {gn.loss:.10g} "
            f"{gn.iterations} iterations, {gn.rollouts:.2f} rollouts, "
            f"cpu {gn_cpu[-1]:.3f} s, wall {gn_wall[-1]:.3f} s",
            flush=True,
        )
    gn_cpu_s, gn_wall_s = float(np.median(gn_cpu)), float(np.median(gn_wall))
    sp = scipy_fit(data, params, args.repeats)
    print(
        f"scipy least_squares (trf, exact jac): mu {sp['mu']:.6f} loss {sp['loss']:.10g} "
        f"{sp['nfev']} evaluations, cpu {sp['cpu_s']:.3f} s ({sp['cpu_s'] / gn_cpu_s:.2f}x the "
        "shared core)",
        flush=True,
    )

    target = gn.loss * (1.0 + SAME_LOSS_RTOL)
    history: list = []
    print(f"adam: lr 0.01, batch 1024, until loss <= {target:.10g} or {adam_cap} steps", flush=True)
    adam = fit_adam(data, params, max_steps=adam_cap, target_loss=target, history=history)
    reached = adam.status == "target_reached"
    last = history[-1]
    near_limit = gn.loss * (1.0 + NEAR_LOSS_RTOL)
    near = next((h for h in history if h[3] <= near_limit), None)
    # "Settled": from this step on, every later loss stays within the tolerance.
    settled = None
    for h in reversed(history):
        if h[3] > near_limit:
            break
        settled = h
    print(
        f"adam: {adam.status} after {adam.iterations} steps, mu {adam.mu:.6f}, loss "
        f"{adam.loss:.10g}, cpu {last[2]:.3f} s, wall {last[1]:.3f} s",
        flush=True,
    )
    adam_cpu = last[2]
    result = {
        "benchmark": "fit_speed",
        "quick": bool(args.quick),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "windows": data.n_windows,
        "horizon": data.horizon,
        "dt_s": data.dt,
        "mu_true": args.mu,
        "noise": not args.noise_free,
        "gauss_newton": {
            "cpu_s": gn_cpu_s,
            "wall_s": gn_wall_s,
            "loss": gn.loss,
            "mu": gn.mu,
            "mu_std": float(gn.std[0]),
            "iterations": gn.iterations,
            "rollouts": gn.rollouts,
        },
        "scipy_least_squares": {**sp, "cpu_ratio_vs_core": sp["cpu_s"] / gn_cpu_s},
        "adam": {
            "reached": reached,
            "steps": adam.iterations,
            "cpu_s": adam_cpu,
            "wall_s": last[1],
            "loss": adam.loss,
            "mu": adam.mu,
            "rollouts": adam.rollouts,
            "steps_within_1e-6": None if near is None else near[0],
            "cpu_s_within_1e-6": None if near is None else near[2],
            "steps_settled_within_1e-6": None if settled is None else settled[0],
            "cpu_s_settled_within_1e-6": None if settled is None else settled[2],
        },
        "speedup": adam_cpu / gn_cpu_s,
        "speedup_within_1e-6": None if near is None else near[2] / gn_cpu_s,
        "speedup_settled_within_1e-6": None if settled is None else settled[2] / gn_cpu_s,
        "work_ratio": adam.rollouts / gn.rollouts,
        "gn_loss_le_adam_loss": bool(gn.loss <= adam.loss * (1.0 + SAME_LOSS_RTOL)),
    }
    print(
        f"speed-up (CPU, to the same loss): {result['speedup']:.1f}x"
        + ("" if reached else " (lower bound: Adam hit the cap)")
        + ("" if near is None else f"; to within 1e-6 of it: {result['speedup_within_1e-6']:.1f}x")
    )
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
