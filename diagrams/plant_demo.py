"""The plant-only demo diagram: ``VehiclePlant`` driven by an open-loop input profile.

Used by ``pcvfe demo``; the drive is written to a drive log (``docs/drive_log.md``) in chunks as
the simulation goes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, Multiplexer, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.runs.drivelog import DriveLogWriter
from pcvfe_drake.systems.vehicle_plant import VehiclePlant
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import INPUT_NAMES, NU, NX, STATE_NAMES


@dataclass
class PlantDemoResult:
    """The end of a demo drive: final state (ST order), true mu and terrain there, the log."""

    final_state: np.ndarray
    true_mu: float
    terrain: str
    log_path: Path
    rows: int


def run_plant_demo(
    params: VehicleParams,
    terrain_map: TerrainMap,
    inputs: Callable[[np.ndarray], np.ndarray],
    *,
    x0,
    duration_s: float,
    out_dir: Path,
    truth: str = "st",
    log_period_s: float = 0.02,
    chunk_s: float = 1.0,
) -> PlantDemoResult:
    """Drives the plant with ``inputs(t) -> (N, 2)`` for ``duration_s`` [s] from ``x0``.

    The input profile is sampled every 10 ms (first-order hold); ``out_dir/drive_log.csv`` is
    appended every ``chunk_s`` of simulated time.
    """
    builder = DiagramBuilder()
    plant = builder.AddNamedSystem("plant", VehiclePlant(params, terrain_map, truth=truth, x0=x0))
    times = np.arange(0.0, duration_s + 0.01, 0.01)
    profile = PiecewisePolynomial.FirstOrderHold(times, inputs(times).T)
    source = builder.AddNamedSystem("open_loop", TrajectorySource(profile))
    builder.Connect(source.get_output_port(), plant.get_actuation_input_port())
    mux = builder.AddNamedSystem("log_mux", Multiplexer([NX, NU, 1, 1]))
    builder.Connect(plant.get_state_output_port(), mux.get_input_port(0))
    builder.Connect(source.get_output_port(), mux.get_input_port(1))
    builder.Connect(plant.get_true_mu_output_port(), mux.get_input_port(2))
    builder.Connect(plant.get_true_terrain_output_port(), mux.get_input_port(3))
    logger = LogVectorOutput(mux.get_output_port(), builder, publish_period=log_period_s)
    diagram = builder.Build()
    diagram.set_name("plant_demo")

    simulator = Simulator(diagram)
    simulator.Initialize()
    out_dir.mkdir(parents=True, exist_ok=True)
    log_path = out_dir / "drive_log.csv"
    names = np.array(terrain_map.names + [""], dtype=object)
    with DriveLogWriter(log_path) as writer:
        t = 0.0
        while t < duration_s - 1e-9:
            t = min(t + chunk_s, duration_s)
            simulator.AdvanceTo(t)
            log = logger.FindMutableLog(simulator.get_context())
            data = log.data()
            if log.num_samples():
                chunk = {"t": log.sample_times().copy()}
                for i, name in enumerate((*STATE_NAMES, *INPUT_NAMES)):
                    chunk[name] = data[i].copy()
                chunk["mu_true"] = data[NX + NU].copy()
                chunk["terrain"] = names[data[NX + NU + 1].astype(int)]
                writer.append(chunk)
                log.Clear()
        rows = writer.rows_written

    context = plant.GetMyContextFromRoot(simulator.get_context())
    k = int(plant.get_true_terrain_output_port().Eval(context)[0])
    return PlantDemoResult(
        final_state=np.array(plant.get_state_output_port().Eval(context)),
        true_mu=float(plant.get_true_mu_output_port().Eval(context)[0]),
        terrain=terrain_map.terrains[k].name if k >= 0 else "",
        log_path=log_path,
        rows=rows,
    )
