"""The UKF baseline's library (filterpy) against the project's use of it: the cost of one step.

``pcvfe_drake.estimation.ukf.FrictionUkf`` is filterpy's ``UnscentedKalmanFilter`` (Merwe
sigma points, 8 states: the ST state and mu) with one change: the 17 sigma points go through
the process model (one RK4 step of the ST model) in one vectorised call instead of filterpy's
loop over sigma points. Nothing to race: this measures what one filter step costs, for

* ours: ``FrictionUkf.step`` (predict with the batched sigma points, update);
* filterpy as documented: the same filter (same points, Q, R, process and measurement
  functions) with filterpy's own ``UnscentedKalmanFilter``, whose ``predict`` calls ``fx`` once
  per sigma point;

on a 20 s drive of the ST model at the filter's 100 Hz (sinusoidal steering and acceleration,
mu 0.6, the sensing model's noise), both filters fed the same measurements; the estimates agree
(reported: largest |mu| difference). CPU time per step (median, p95) and its share of the
10 ms period.

Usage: python benchmarks/peers_ukf.py [--quick]. Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import time

import numpy as np

from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import NX, rk4_step

SIGMA = np.array([0.02, 0.02, 0.001, 0.015, 0.002, 0.002, 0.003])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="5 s instead of 20 s")
    args = ap.parse_args()
    result: dict = {"benchmark": "peers_ukf", "quick": args.quick, "cpu_count": os.cpu_count()}
    try:
        from filterpy.kalman import UnscentedKalmanFilter

        from pcvfe_drake.estimation.ukf import FrictionUkf, UkfConfig
    except Exception as exc:
        result["peers_missing"] = {"filterpy": f"{type(exc).__name__}: {exc}"}
        print(f"PEER MISSING: filterpy ({exc})", flush=True)
        print(json.dumps(result))
        return 0
    result["filterpy"] = importlib.metadata.version("filterpy")
    p = ford_escort()
    cfg = UkfConfig()
    dt = cfg.period_s
    n = int((5.0 if args.quick else 20.0) / dt)
    rng = np.random.default_rng(0)
    t = np.arange(n) * dt
    u = np.column_stack([0.3 * np.cos(0.8 * t), 1.5 * np.sin(0.3 * t)])
    x = np.array([0.0, 0.0, 0.0, 10.0, 0.0, 0.0, 0.0])
    theta = np.array([0.6, p.C_Sf, p.C_Sr])
    xs = np.empty((n, NX))
    for k in range(n):
        xs[k] = x
        x = rk4_step(x, u[k], p, dt, theta=theta)
    z = xs + rng.normal(size=xs.shape) * SIGMA

    ours = FrictionUkf(p, SIGMA, cfg)
    stock = UnscentedKalmanFilter(
        dim_x=NX + 1,
        dim_z=NX,
        dt=dt,
        hx=ours._hx,
        fx=lambda s, dt, u: ours._fx(s[None, :], dt, u)[0],
        points=ours._ukf.points_fn,
    )
    stock.Q, stock.R = ours.Q, ours.R

    xo, po = ours.initial(z[0])
    stock.x, stock.P = xo.copy(), po.copy()
    t_ours, t_stock, mu_diff = [], [], []
    for k in range(1, n):
        c = time.process_time()
        xo, po = ours.step(xo, po, u[k - 1], z[k])
        t_ours.append(time.process_time() - c)
        c = time.process_time()
        stock.predict(u=u[k - 1])
        stock.update(z[k])
        t_stock.append(time.process_time() - c)
        mu_diff.append(abs(float(stock.x[NX]) - float(xo[NX])))
    a, b = np.array(t_ours) * 1e3, np.array(t_stock) * 1e3
    result.update(
        {
            "steps": n - 1,
            "load_avg_1min": os.getloadavg()[0],
            "ours_step_cpu_ms_median": float(np.median(a)),
            "ours_step_cpu_ms_p95": float(np.percentile(a, 95)),
            "filterpy_step_cpu_ms_median": float(np.median(b)),
            "filterpy_step_cpu_ms_p95": float(np.percentile(b, 95)),
            "ratio_filterpy_over_ours_median": float(np.median(b) / np.median(a)),
            "ours_share_of_period": float(np.median(a) / (dt * 1e3)),
            "max_abs_mu_difference": float(max(mu_diff)),
            "final_mu_ours": float(xo[NX]),
            "true_mu": 0.6,
        }
    )
    print(
        f"one UKF step (CPU): ours {np.median(a):.3f} ms median, {np.percentile(a, 95):.3f} p95; "
        f"filterpy's loop {np.median(b):.3f} / {np.percentile(b, 95):.3f} ms; "
        f"mu difference <= {max(mu_diff):.2e}",
        flush=True,
    )
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
