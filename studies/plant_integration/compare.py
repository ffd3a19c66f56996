"""The multi-body truth's integration: Drake's continuous RK3 against the compiled discrete
update, on the commands of a driven lap, each against a fine reference.

A drive log's commands (``steer_rate``, ``accel`` per row, held to the next row) are replayed
from its first true state on the ``paper`` world through
- Drake's error-controlled RK3 on the continuous MB state (``mb_integration: continuous``) at
  accuracy 1e-7 (the reference) and at the accuracies given (``paper_eval`` drove at 1e-3);
- the discrete update of the plant's default (``mb_method: rk23``: ``MbTruth.advance`` every
  10 ms, mu looked up once per update).
It prints each one's CPU time, derivative evaluations and largest distance from the
reference's position over the replay, then one JSON object.

Usage: python studies/plant_integration/compare.py [--log runs/x/drive_log.csv] [--seconds 40]
Without --log it first drives ``paper_eval`` with the oracle for that long into a temporary
folder.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from pcvfe_drake.diagrams.world_io import world_terrain_map
from pcvfe_drake.systems.vehicle_plant import VehiclePlant
from pcvfe_drake.vehicle.params import ford_escort

TRUE_STATE = ["true_sx", "true_sy", "true_delta", "true_v", "true_psi", "true_psi_dot", "true_beta"]


def replay(terrain_map, t, commands, x0, **plant_kwargs):
    """Positions (len(t), 2) at the log's rows, CPU seconds, derivative evaluations."""
    builder = DiagramBuilder()
    plant = builder.AddSystem(
        VehiclePlant(ford_escort(), terrain_map, truth="mb", x0=x0, **plant_kwargs.pop("plant"))
    )
    held = PiecewisePolynomial.ZeroOrderHold(
        np.append(t, t[-1] + 1.0), np.vstack([commands, commands[-1:]]).T
    )
    source = builder.AddSystem(TrajectorySource(held))
    builder.Connect(source.get_output_port(), plant.get_actuation_input_port())
    simulator = Simulator(builder.Build())
    if "accuracy" in plant_kwargs:
        ResetIntegratorFromFlags(simulator, "runge_kutta3", 0.01)
        simulator.get_mutable_integrator().set_target_accuracy(plant_kwargs["accuracy"])
    simulator.Initialize()
    context = plant.GetMyContextFromRoot(simulator.get_context())
    positions = []
    c0 = time.process_time()
    for tk in t:
        simulator.AdvanceTo(tk)
        positions.append(plant.get_state_output_port().Eval(context)[:2].copy())
    cpu = time.process_time() - c0
    evals = simulator.get_integrator().get_num_derivative_evaluations()
    return np.array(positions), cpu, int(evals)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, help="a drive log (default: drive one first)")
    ap.add_argument("--seconds", type=float, default=40.0, help="replayed length [s]")
    ap.add_argument("--accuracies", type=float, nargs="+", default=[1e-3, 1e-4])
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        log = args.log
        if log is None:
            out = Path(tmp) / "drive"
            subprocess.run(
                [sys.executable, "-m", "pcvfe_drake.cli", "simulate", "paper_eval", "--duration",
                 str(args.seconds), "--estimator", "oracle", "--no-meshcat", "--no-progress",
                 "--out", str(out)],
                check=True, stdout=subprocess.DEVNULL,
            )  # fmt: skip
            log = out / "drive_log.csv"
        rows = pd.read_csv(log)
    rows = rows[rows.t <= rows.t.iloc[0] + args.seconds + 1e-9]
    t = rows.t.to_numpy()
    commands = rows[["steer_rate", "accel"]].to_numpy()
    x0 = rows[TRUE_STATE].to_numpy()[0]
    terrain_map = world_terrain_map("paper")
    print(f"{len(t)} rows, {t[-1] - t[0]:.1f} s from {log}")
    variants = {"reference (continuous, RK3 1e-7)": {"plant": {"mb_integration": "continuous"},
                                                      "accuracy": 1e-7}}  # fmt: skip
    for accuracy in args.accuracies:
        variants[f"continuous, RK3 {accuracy:g}"] = {
            "plant": {"mb_integration": "continuous"},
            "accuracy": accuracy,
        }
    variants["discrete rk23 (default)"] = {"plant": {}}
    result = {}
    reference = None
    for name, kwargs in variants.items():
        positions, cpu, evals = replay(terrain_map, t, commands, x0, **kwargs)
        if reference is None:
            reference = positions
        gap = np.hypot(*(positions - reference).T)
        result[name] = {
            "cpu_s": round(cpu, 3),
            "derivative_evaluations_drake": evals,
            "max_distance_from_reference_m": round(float(gap.max()), 4),
            "median_distance_from_reference_m": round(float(np.median(gap)), 5),
        }
        print(f"  {name:36s} {result[name]}")
    print(json.dumps({"study": "plant_integration", "seconds": args.seconds, "variants": result}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
