"""Benchmark: real-time factor of the VehiclePlant alone in a Drake Simulator.

Constant input, 60 s of simulated time (10 s with --quick) on the default terrain map: the car
starts at (0, -45) m heading east at 10 m/s with 0.06 rad of steering and holds it, so it
circles (radius ~40 m) through all four quadrants and the transition strips, its friction
changing with the terrain. Continuous states under Drake's default integrator
(error-controlled RK3, accuracy 1e-4).

Measured for the ST truth (target >= 50x real time) and the multi-body truth (target >= 5x): its
default, the discrete 100 Hz update by compiled error-controlled steps (``rk23``), and for
reference the continuous state under Drake's RK3 and the discrete update with 1 ms RK4 substeps
in Python (at most 10 s of it). To show what limits each, the same run also measures the cost of
one bare derivative evaluation (``st_dynamics`` on one state; the multi-body derivative as the
plant evaluates it, ``MbTruth.rhs`` with the compiled ``mb_kernel``, and, for reference, the
package's ``vehicle_dynamics_mb`` in Python) and counts the derivative evaluations Drake made.

Usage: python benchmarks/plant_realtime.py [--quick]   (last stdout line: one JSON object)
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource
from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb

from pcvfe_drake.diagrams.world_io import world_terrain_map
from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.systems.vehicle_plant import VehiclePlant
from pcvfe_drake.vehicle.mb_truth import MbTruth
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import st_dynamics

X0 = np.array([0.0, -45.0, 0.06, 10.0, 0.0, 0.0, 0.0])
U = np.array([0.0, 0.0])


def run_plant(terrain_map, duration_s: float, **plant_kwargs) -> dict:
    builder = DiagramBuilder()
    plant = builder.AddNamedSystem(
        "plant", VehiclePlant(ford_escort(), terrain_map, x0=X0, **plant_kwargs)
    )
    source = builder.AddNamedSystem("constant_input", ConstantVectorSource(U))
    builder.Connect(source.get_output_port(), plant.get_actuation_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.Initialize()
    t0 = time.perf_counter()
    simulator.AdvanceTo(duration_s)
    wall = time.perf_counter() - t0
    context = plant.GetMyContextFromRoot(simulator.get_context())
    x = plant.get_state_output_port().Eval(context)
    integrator = simulator.get_integrator()
    return {
        "realtime_factor": round(duration_s / wall, 2),
        "wall_s": round(wall, 3),
        "derivative_evaluations": int(integrator.get_num_derivative_evaluations()),
        "steps": int(integrator.get_num_steps_taken()),
        "final_speed_mps": round(float(x[3]), 3),
        "final_terrain": terrain_map.terrains[
            int(plant.get_true_terrain_output_port().Eval(context)[0])
        ].name,
    }


def per_call_s(fn, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s of simulated time, not 60 s")
    args = parser.parse_args()
    duration = 10.0 if args.quick else 60.0
    paper = world_terrain_map("paper")
    terrain_map = TerrainMap.from_label_image(
        paper.labels,
        paper.terrains,
        x_min_m=paper.x_min_m,
        y_min_m=paper.y_min_m,
        resolution_m=paper.resolution_m,
        outside="concrete",
    )

    params = ford_escort()
    st_call = per_call_s(lambda: st_dynamics(X0, U, params), 2000)
    mb = MbTruth()
    x_mb = mb.initial_state(X0)
    p_mb = mb.parameters_for_mu(0.6)
    pv_mb = mb.parameter_vector_for_mu(0.6)
    mb.rhs(x_mb, U, pv_mb)  # compiled (or loaded from numba's cache) before it is timed
    mb_call = per_call_s(lambda: mb.rhs(x_mb, U, pv_mb), 20000)
    package_call = per_call_s(lambda: vehicle_dynamics_mb(x_mb.tolist(), U.tolist(), p_mb), 2000)
    print(
        f"bare derivative: st_dynamics {st_call * 1e6:.0f} us, MB {mb_call * 1e6:.1f} us "
        f"(the package in Python: {package_call * 1e6:.0f} us)"
    )

    results = {}
    for name, seconds, kwargs in (
        ("st", duration, {"truth": "st"}),
        ("mb", duration, {"truth": "mb"}),
        ("mb_continuous", duration, {"truth": "mb", "mb_integration": "continuous"}),
        # The slow reference variant runs at most 10 s (2 s with --quick).
        (
            "mb_discrete_rk4",
            min(duration, 2.0 if args.quick else 10.0),
            {"truth": "mb", "mb_method": "rk4"},
        ),
    ):
        print(f"{name}: simulating {seconds:g} s ...", flush=True)
        r = run_plant(terrain_map, seconds, **kwargs)
        r["simulated_s"] = seconds
        results[name] = r
        print(f"  real-time factor {r['realtime_factor']}x ({r['wall_s']} s wall), {r}")

    def share(key: str, call_s: float) -> float:
        r = results[key]
        # the evaluations Drake's integrator made: none for a discrete state
        return round(r["derivative_evaluations"] * call_s / r["wall_s"], 2)

    out = {
        "benchmark": "plant_realtime",
        "quick": args.quick,
        "simulated_s": duration,
        "st_realtime_factor": results["st"]["realtime_factor"],
        "mb_realtime_factor": results["mb"]["realtime_factor"],
        "mb_continuous_realtime_factor": results["mb_continuous"]["realtime_factor"],
        "mb_discrete_rk4_realtime_factor": results["mb_discrete_rk4"]["realtime_factor"],
        "target_st": 50,
        "target_mb": 5,
        "st_derivative_us": round(st_call * 1e6, 1),
        "mb_derivative_us": round(mb_call * 1e6, 1),
        "mb_package_derivative_us": round(package_call * 1e6, 1),
        "st_derivative_share_of_wall": share("st", st_call),
        "mb_continuous_derivative_share_of_wall": share("mb_continuous", mb_call),
        "details": results,
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    print(
        f"ST {out['st_realtime_factor']}x (target 50x), MB {out['mb_realtime_factor']}x "
        f"(target 5x); bare derivative evaluations take {out['st_derivative_share_of_wall']:.0%} "
        f"(ST) and {out['mb_continuous_derivative_share_of_wall']:.0%} (MB, continuous) of the "
        f"wall time; MB continuous {out['mb_continuous_realtime_factor']}x"
    )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
