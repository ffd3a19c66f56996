"""``pcvfe demo``: a short plant-only drive with an open-loop steering/acceleration profile."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.params import load_vehicle
from pcvfe_drake.vehicle import INPUT_NAMES, STATE_NAMES, STATE_UNITS, rk4_step

DT_S = 0.01


def open_loop_input(t_s: float) -> np.ndarray:
    """Demo profile [steer_rate rad/s, accel m/s^2]: accelerate, then a left-right steering wave."""
    accel = 2.0 if t_s < 3.0 else 0.0
    steer_rate = 0.2 * np.sin(2.0 * np.pi * 0.25 * (t_s - 1.0)) if t_s >= 1.0 else 0.0
    return np.array([steer_rate, accel])


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="short plant-only drive (open-loop inputs), prints the final state, writes a log",
        description=(
            "Drive the single-track plant with an open-loop steering/acceleration profile for a "
            "few seconds, print the final state and write a drive log (CSV) to --out."
        ),
    )
    parser.add_argument("--duration", type=float, default=5.0, help="simulated time [s]")
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="output folder")
    parser.add_argument("--vehicle", default=None, help="vehicle preset or YAML file")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not np.isfinite(args.duration) or args.duration <= 0:
        raise ValueError(f"--duration must be a positive number of seconds, got {args.duration}")
    params = load_vehicle(args.vehicle)
    n = int(round(args.duration / DT_S))
    x = np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    rows = []
    for k in range(n + 1):
        t = k * DT_S
        u = open_loop_input(t)
        rows.append([t, *x, *u])
        if k < n:
            x = rk4_step(x, u, params, DT_S)
    df = pd.DataFrame(rows, columns=["t", *STATE_NAMES, *INPUT_NAMES])
    args.out.mkdir(parents=True, exist_ok=True)
    log_path = args.out / "drive_log.csv"
    df.to_csv(log_path, index=False)
    print(f"final state after {n * DT_S:.2f} s ({params.name}):")
    for name, unit, value in zip(STATE_NAMES, STATE_UNITS, x, strict=True):
        print(f"  {name:8s} {value:12.4f}  [{unit}]")
    print(f"drive log: {log_path}")
    return 0
