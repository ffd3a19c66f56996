"""Closed-loop laps of the tracking NMPC with the true friction given.

Runs the Ford Escort on the ``slalom`` course on each uniform terrain (mu 0.3, 0.45, 0.6, 0.8)
and on the four-terrain map of the shipped ``paper`` world, the KMPC baseline on the
four-terrain map, and the RoboRacer on ``slalom_small``; the truth is the ST model
(RK4 at 10 ms). With ``--mb`` also CommonRoad's multi-body model (saturating Pacejka tires) on the
four-terrain map: at the course's 5 m/s, with the speed cap raised to 12 m/s, and (informative,
not a pass criterion) at 12 m/s believing mu = 1 everywhere. Otherwise the controller is told the
true mu under the car at each update.

Pass criteria per run: at least one full lap, lateral tracking RMS <= 0.3 m (scaled by 1/5 on
the small course), and no failure: the car never leaves the course (|lateral error| > the
course's half width: 3 m, 0.6 m small) and never spins (|course-angle error| > 60 deg or
|beta| > 30 deg).

Usage: ``python validation/nmpc_laps.py [--quick] [--mb]``; the last stdout line is a JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from pcvfe_drake.control.closed_loop import MbTruthPlant, simulate_closed_loop
from pcvfe_drake.control.course import initial_state, load_course
from pcvfe_drake.control.nmpc import NmpcConfig, NmpcController
from pcvfe_drake.vehicle.params import ford_escort, roboracer

RMS_LIMIT_M = 0.3


def run(
    label,
    course,
    params,
    config,
    mu_at,
    laps,
    truth=None,
    rms_limit=RMS_LIMIT_M,
    theta_hat=None,
    terrain=None,
):
    ctrl = NmpcController(course, params, config)
    prof = ctrl.profile(float(mu_at(np.array(course.sample(0.0)[:2]))))
    x0 = initial_state(course, params, float(prof.speed_at(0.0)))
    t0 = time.perf_counter()
    res = simulate_closed_loop(
        ctrl,
        x0,
        duration_s=1.6 * laps * prof.lap_time + 5.0,
        mu_at=mu_at,
        truth=truth,
        theta_hat=theta_hat,
        stop_after_laps=laps,
    )
    wall = time.perf_counter() - t0
    m = res.metrics(course)
    m.update(
        label=label,
        course=course.name,
        vehicle=params.name,
        model=config.model,
        truth="mb" if truth is not None else "st",
        wall_s=wall,
        lap_time_s=m["duration_s"] / max(m["laps"], 1e-9),
        rms_limit_m=rms_limit,
    )
    if terrain is not None:  # seconds driven on each terrain (the fitter needs ~20 s each)
        names = np.asarray(terrain.name_at(res.x[:-1, :2]))
        dt = np.diff(res.t)
        m["terrain_time_s"] = {str(n): float(dt[names == n].sum()) for n in np.unique(names)}
    m["passed"] = bool(
        m["laps"] >= laps - 1e-6 and m["lateral_rms_m"] <= rms_limit and not m["failure"]
    )
    print(
        f"{label:28s} laps {m['laps']:.2f}  lateral RMS {m['lateral_rms_m'] * 100:6.2f} cm  "
        f"max {m['lateral_max_m'] * 100:6.1f} cm  v {m['mean_speed_mps']:.2f} m/s  "
        f"fallbacks {m['fallbacks']}  update median {m['update_ms_median']:.2f} ms  "
        f"p95 {m['update_ms_p95']:.2f} ms  {'PASS' if m['passed'] else 'FAIL ' + m['failure']}",
        flush=True,
    )
    return m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a quarter lap per run, fewer runs")
    ap.add_argument("--mb", action="store_true", help="also a lap on the multi-body truth")
    args = ap.parse_args(argv)
    laps = 0.25 if args.quick else 1.0

    ford = ford_escort()
    slalom = load_course("slalom")
    small = load_course("slalom_small")
    cfg = NmpcConfig()
    kmpc = NmpcConfig(model="ks")
    results = []
    mus = (0.3, 0.8) if args.quick else (0.3, 0.45, 0.6, 0.8)
    for mu in mus:
        results.append(run(f"NMPC uniform mu={mu}", slalom, ford, cfg, lambda xy, mu=mu: mu, laps))
    from pcvfe_drake.diagrams.world_io import world_terrain_map

    terrain = world_terrain_map("paper")

    def mixed(xy):
        return float(terrain.mu_at(np.asarray(xy, dtype=float)))

    results.append(run("NMPC four-terrain map", slalom, ford, cfg, mixed, laps, terrain=terrain))
    results.append(run("KMPC four-terrain map", slalom, ford, kmpc, mixed, laps, terrain=terrain))
    rr = roboracer()
    results.append(
        run(
            "NMPC RoboRacer mu=0.6",
            small,
            rr,
            cfg,
            lambda xy: 0.6,
            laps,
            rms_limit=RMS_LIMIT_M / 5,
        )
    )
    if args.mb:
        results.append(
            run("NMPC four-terrain, MB truth", slalom, ford, cfg, mixed, laps, MbTruthPlant())
        )
        fast = NmpcConfig(max_speed_mps=12.0)
        results.append(
            run("NMPC 12 m/s cap, MB truth", slalom, ford, fast, mixed, laps, MbTruthPlant())
        )
        # Informative: the same car believing mu = 1.0 everywhere (expected to slide off on the
        # low-friction quadrants, where the saturating MB tires cannot deliver the grip).
        over = run(
            "12 m/s, believes mu=1, MB",
            slalom,
            ford,
            fast,
            mixed,
            laps,
            MbTruthPlant(),
            theta_hat=lambda t, x: np.array([1.0, ford.C_Sf, ford.C_Sr]),
        )
        over["informative_only"] = True
        results.append(over)
    summary = {
        "benchmark": "nmpc_laps",
        "quick": args.quick,
        "laps_per_run": laps,
        "rms_limit_m": RMS_LIMIT_M,
        "all_passed": all(r["passed"] for r in results if not r.get("informative_only")),
        "target": f"every lap with the true friction: no failure, lateral RMS <= {RMS_LIMIT_M} m",
        "runs": results,
    }
    summary["passed"] = summary["all_passed"]
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
