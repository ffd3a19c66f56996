"""``pcvfe demo``: a short plant-only drive with an open-loop steering/acceleration profile.

The VehiclePlant (ST or multi-body truth, friction from the default terrain map) is driven by a
fixed profile; the drive is logged as it goes (``drive_log.csv``, the documented drive-log
format) and the final state is printed.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from pcvfe_drake.runs.output_paths import check_output_dir
from pcvfe_drake.vehicle.params import TRUTH_MODELS, load_vehicle
from pcvfe_drake.vehicle.single_track import STATE_NAMES, STATE_UNITS

LOG_PERIOD_S = 0.02
CHUNK_S = 1.0
START_STATE = (-30.0, -35.0, 0.0, 8.0, 0.0, 0.0, 0.0)
"""On sand, heading east (+x) at 8 m/s, towards the concrete."""
MAX_DURATION_S = 6.0
"""The profile keeps the car on the default map for this long."""


def open_loop_input(t_s: np.ndarray) -> np.ndarray:
    """Demo profile, (N,) times [s] -> (N, 2) [steer_rate rad/s, accel m/s^2]: accelerate gently
    for 3 s, then a left-right steering wave from t = 1 s (one full period per 4 s)."""
    t_s = np.asarray(t_s, dtype=float)
    accel = np.where(t_s < 3.0, 1.0, 0.0)
    steer_rate = np.where(t_s >= 1.0, 0.08 * np.sin(2.0 * np.pi * 0.25 * (t_s - 1.0)), 0.0)
    return np.stack([steer_rate, accel], axis=1)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="short plant-only drive (open-loop inputs): prints the final state, writes a log",
        description=(
            "Drive the simulated vehicle (VehiclePlant on the default terrain map) with an "
            "open-loop steering/acceleration profile, print the final state and write the drive "
            "log OUT/drive_log.csv (written as the run goes; format in docs/drive_log.md)."
        ),
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=5.0,
        help=f"simulated time [s], at most {MAX_DURATION_S:g}",
    )
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="output folder")
    parser.add_argument(
        "--truth", choices=TRUTH_MODELS, default="st", help="truth model of the plant"
    )
    parser.add_argument("--vehicle", default=None, help="vehicle preset or YAML file")
    parser.add_argument(
        "--world", default="paper", help="world: shipped name or world file (docs/worlds.md)"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.duration) and 0 < args.duration <= MAX_DURATION_S):
        raise ValueError(f"--duration must be in (0, {MAX_DURATION_S:g}] s, got {args.duration}")
    check_output_dir(args.out)
    # The diagram lives in pcvfe_drake.diagrams (imported here, not at module import time, so
    # that the core package stays free of pydrake).
    from pcvfe_drake.diagrams.plant_demo import run_plant_demo
    from pcvfe_drake.diagrams.world_io import world_terrain_map

    params = load_vehicle(args.vehicle)
    result = run_plant_demo(
        params,
        world_terrain_map(args.world),
        open_loop_input,
        x0=START_STATE,
        duration_s=args.duration,
        out_dir=args.out,
        truth=args.truth,
        log_period_s=LOG_PERIOD_S,
        chunk_s=CHUNK_S,
    )
    print(f"final state after {args.duration:g} s ({params.name}, {args.truth} truth):")
    for name, unit, value in zip(STATE_NAMES, STATE_UNITS, result.final_state, strict=True):
        print(f"  {name:8s} {value:12.4f}  [{unit}]")
    print(f"  terrain  {result.terrain} (true mu {result.true_mu:g})")
    print(f"drive log: {result.log_path} ({result.rows} rows)")
    return 0
