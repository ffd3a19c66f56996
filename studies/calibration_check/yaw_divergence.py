"""The Ford at 8 m/s on a straight, no steering, on the multi-body truth: the yaw rate and
LSODA's right-hand-side evaluations per 0.05 s interval.

    python studies/calibration_check/yaw_divergence.py MAPPING MU [--steps 60]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy.integrate import solve_ivp

from pcvfe_drake.vehicle.mb_truth import WHEEL_SPEEDS, MbTruth, st_state


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mapping")
    ap.add_argument("mu", type=float)
    ap.add_argument("--steps", type=int, default=60)
    args = ap.parse_args()
    truth = MbTruth("ford_escort", friction_scaling=args.mapping)
    x = truth.initial_state(np.array([0, 0, 0, 8.0, 0, 0, 0]))
    p = truth.parameter_vector_for_mu(args.mu)
    rows = []
    for k in range(args.steps):
        xs = st_state(x)
        acc = float(np.clip(0.8 * (8.0 - xs[3]), -3, 2))
        sol = solve_ivp(
            lambda _t, y, a=acc: MbTruth.rhs(y, [0.0, a], p),
            (0, 0.05),
            x,
            method="LSODA",
            rtol=1e-6,
            atol=1e-6,
        )
        x = sol.y[:, -1]
        np.maximum(x[WHEEL_SPEEDS], 0, out=x[WHEEL_SPEEDS])
        rows.append((round(0.05 * (k + 1), 2), float(xs[5]), int(sol.nfev)))
        print(f"t {0.05 * k:5.2f} s  yaw rate {xs[5]:+.5f} rad/s  evaluations {sol.nfev}")
    print(
        json.dumps(
            {
                "mapping": args.mapping,
                "mu": args.mu,
                "max_abs_yaw_rate": max(abs(r) for _, r, _ in rows),
                "max_evaluations": max(n for *_, n in rows),
            }
        )
    )


if __name__ == "__main__":
    main()
