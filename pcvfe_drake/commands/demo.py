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

from pcvfe_drake.params import load_vehicle
from pcvfe_drake.vehicle import INPUT_NAMES, STATE_NAMES, STATE_UNITS

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
        "--truth", choices=("st", "mb"), default="st", help="truth model of the plant"
    )
    parser.add_argument("--vehicle", default=None, help="vehicle preset or YAML file")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.duration) and 0 < args.duration <= MAX_DURATION_S):
        raise ValueError(f"--duration must be in (0, {MAX_DURATION_S:g}] s, got {args.duration}")
    # The CLI layer may use the systems; the core modules never import pydrake.
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput, Multiplexer, TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from pcvfe_drake.drivelog import DriveLogWriter
    from pcvfe_drake.systems.vehicle_plant import VehiclePlant
    from pcvfe_drake.terrain import default_terrain_map

    params = load_vehicle(args.vehicle)
    terrain_map = default_terrain_map()
    builder = DiagramBuilder()
    plant = builder.AddNamedSystem(
        "plant", VehiclePlant(params, terrain_map, truth=args.truth, x0=START_STATE)
    )
    times = np.arange(0.0, args.duration + 0.01, 0.01)
    profile = PiecewisePolynomial.FirstOrderHold(times, open_loop_input(times).T)
    source = builder.AddNamedSystem("open_loop", TrajectorySource(profile))
    builder.Connect(source.get_output_port(), plant.get_actuation_input_port())
    mux = builder.AddNamedSystem("log_mux", Multiplexer([7, 2, 1, 1]))
    builder.Connect(plant.get_state_output_port(), mux.get_input_port(0))
    builder.Connect(source.get_output_port(), mux.get_input_port(1))
    builder.Connect(plant.get_true_mu_output_port(), mux.get_input_port(2))
    builder.Connect(plant.get_true_terrain_output_port(), mux.get_input_port(3))
    logger = LogVectorOutput(mux.get_output_port(), builder, publish_period=LOG_PERIOD_S)
    diagram = builder.Build()
    diagram.set_name("demo")

    simulator = Simulator(diagram)
    simulator.Initialize()
    args.out.mkdir(parents=True, exist_ok=True)
    log_path = args.out / "drive_log.csv"
    names = np.array(terrain_map.names + [""], dtype=object)
    with DriveLogWriter(log_path) as writer:
        t = 0.0
        while t < args.duration - 1e-9:
            t = min(t + CHUNK_S, args.duration)
            simulator.AdvanceTo(t)
            log = logger.FindMutableLog(simulator.get_context())
            data = log.data()
            if log.num_samples():
                chunk = {"t": log.sample_times().copy()}
                for i, name in enumerate((*STATE_NAMES, *INPUT_NAMES)):
                    chunk[name] = data[i].copy()
                chunk["mu_true"] = data[9].copy()
                chunk["terrain"] = names[data[10].astype(int)]
                writer.append(chunk)
                log.Clear()
        rows = writer.rows_written

    context = plant.GetMyContextFromRoot(simulator.get_context())
    x = plant.get_state_output_port().Eval(context)
    mu = plant.get_true_mu_output_port().Eval(context)[0]
    k = int(plant.get_true_terrain_output_port().Eval(context)[0])
    print(f"final state after {args.duration:g} s ({params.name}, {args.truth} truth):")
    for name, unit, value in zip(STATE_NAMES, STATE_UNITS, x, strict=True):
        print(f"  {name:8s} {value:12.4f}  [{unit}]")
    print(f"  terrain  {terrain_map.terrains[k].name} (true mu {mu:g})")
    print(f"drive log: {log_path} ({rows} rows)")
    return 0
