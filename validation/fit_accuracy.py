"""Friction-fit accuracy on the four default terrains: ST truth (noise-free, noisy) and MB truth.

Data: 20 s S-curve drives at ~8 m/s (steering amplitude 0.1 rad at 0.3 Hz, a 5 % speed wave) on
patchy grass (mu 0.3), sand (0.45), concrete (0.6) and brick (0.8), Ford Escort, 100 Hz.

* ST truth: the drives are simulated with the project's single-track model (RK4, 10 ms). Fitted
  noise-free and with the documented measurement noise (``MeasurementNoise``; ``--seeds`` noise
  draws per terrain).
* MB truth: the same input sequences drive CommonRoad's multi-body model
  (``pcvfe_drake.vehicle.mb_truth.MbTruth``, RK4 with 1 ms substeps) with friction scaled per
  terrain in
  both of its modes: ``peak_and_stiffness`` (peak factors and slip stiffnesses scaled with mu, the
  ST model's parametrisation) and ``peak`` (only the peak factors; small-slip stiffness fixed).
  The fit uses the ST model, so its error here is model error; no threshold applies.

Every fit is the default one (mu only, bounded Gauss-Newton, H = 10, stride 5, x0 smoothing 3).

Usage: python validation/fit_accuracy.py [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from pcvfe_drake.estimation.fit_dataset import build_windows
from pcvfe_drake.estimation.fitting import fit_gauss_newton
from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.vehicle.mb_truth import MbTruth
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import STATE_NAMES

TERRAINS = {"patchy_grass": 0.3, "sand": 0.45, "concrete": 0.6, "brick": 0.8}
NOISE_FREE_TOL = 0.01
"""On its own model's noise-free data the fit must find mu to well below any terrain gap."""
NOISY_TOL = 0.05
"""With the documented sensor noise: the tolerance the closed loop is scored by."""


def _fit(t, states, inputs, params) -> dict:
    split = build_windows(t, states, inputs)
    result = fit_gauss_newton(split.by_context[0], params)
    return {
        "mu": result.mu,
        "std": float(result.std[0]),
        "loss": result.loss,
        "windows": result.n_windows,
        "skipped": sum(split.skipped.values()),
        "converged": result.converged,
        "residual_rms": dict(zip(STATE_NAMES, result.residual_rms.tolist(), strict=True)),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s drives, 2 seeds, one MB mode")
    parser.add_argument("--seeds", type=int, default=None, help="noise draws (default 5)")
    parser.add_argument("--duration", type=float, default=None, help="drive length [s]")
    args = parser.parse_args()
    duration = args.duration or (10.0 if args.quick else 20.0)
    seeds = args.seeds or (2 if args.quick else 5)
    modes = ("peak_and_stiffness",) if args.quick else ("peak_and_stiffness", "peak")
    params = ford_escort()
    names = list(TERRAINS)
    mus = np.array([TERRAINS[n] for n in names])

    t, S, U = s_curve_drive(params, mus, duration_s=duration, phase_rad=[0.0, 1.0, 2.0, 3.0])
    out: dict = {"benchmark": "fit_accuracy", "quick": bool(args.quick), "duration_s": duration}

    st_clean, st_noisy = {}, {}
    for i, name in enumerate(names):
        st_clean[name] = _fit(t, S[i], U[i], params)
        errors = []
        for seed in range(seeds):
            measured = MeasurementNoise().apply(S[i], np.random.default_rng(seed))
            errors.append(_fit(t, measured, U[i], params)["mu"] - mus[i])
        st_noisy[name] = {
            "mean_error": float(np.mean(errors)),
            "max_abs_error": float(np.max(np.abs(errors))),
            "errors": errors,
        }
        print(
            f"ST {name:13s} mu {mus[i]:.2f}: noise-free {st_clean[name]['mu']:.5f} "
            f"(err {st_clean[name]['mu'] - mus[i]:+.5f}); noisy max |err| "
            f"{st_noisy[name]['max_abs_error']:.4f} over {seeds} seeds",
            flush=True,
        )
    out["st_noise_free"] = {n: {**v, "error": v["mu"] - TERRAINS[n]} for n, v in st_clean.items()}
    out["st_noisy"] = st_noisy
    out["st_noise_free_max_abs_error"] = max(
        abs(v["mu"] - TERRAINS[n]) for n, v in st_clean.items()
    )
    out["st_noisy_max_abs_error"] = max(v["max_abs_error"] for v in st_noisy.values())

    out["mb"] = {}
    for mode in modes:
        truth = MbTruth("ford_escort", friction_scaling=mode)
        rows = {}
        for i, name in enumerate(names):
            c0 = time.perf_counter()
            X_st, _ = truth.simulate(S[i, 0], U[i, :-1], 0.01, float(mus[i]), method="rk4")
            fit = _fit(t, X_st, U[i], params)
            fit["error"] = fit["mu"] - mus[i]
            fit["mean_speed_mps"] = float(np.mean(X_st[:, 3]))
            rows[name] = fit
            print(
                f"MB[{mode}] {name:13s} mu {mus[i]:.2f}: fitted {fit['mu']:.4f} "
                f"(err {fit['error']:+.4f}, loss {fit['loss']:.3g}, "
                f"sim {time.perf_counter() - c0:.1f} s)",
                flush=True,
            )
        out["mb"][mode] = rows
    out["target"] = (
        f"ST truth: |mu error| <= {NOISE_FREE_TOL} noise-free and <= {NOISY_TOL} with the "
        "documented measurement noise on every terrain (the multi-body rows are informative)"
    )
    out["passed"] = bool(
        out["st_noise_free_max_abs_error"] <= NOISE_FREE_TOL
        and out["st_noisy_max_abs_error"] <= NOISY_TOL
    )
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
