"""Does a command delay alone bias the friction estimates? The all-in-one simulation with the
actuation delayed by a fixed time and nothing else changed.

The LCM rehearsal (``benchmarks/hardware_rehearsal.py``) estimated mu 3-6 % high on every
terrain while the all-in-one loop was exact; over LCM the car applies each command some 37 ms
(median) after the NMPC computed it, while the fitter pairs each state with the command as
computed. This benchmark isolates that one difference: the simulated station of the scenario
behind a sample-and-hold that applies the NMPC's command ``delay`` seconds after each NMPC
update (``ZeroOrderHold`` with the NMPC's period and offset ``delay``: a pure delay for the
NMPC's piecewise-constant command, for delays below one NMPC period). The fitter, the log and
the NMPC see exactly what they see in the all-in-one run; only the plant gets the command late.

Runs the scenario once per delay (0 = the all-in-one baseline, in the same run) and prints the
per-context mu estimates and their relative error against the truth. With ``--lcm-loop`` also
the whole LCM path in one process without load (the hardware station and the vehicle bridge
on one ``memq://`` bus, simulated clock): the LCM loop's structural timing (states taken at
100 Hz checks, commands applied at the bridge's next check) without the stalls of a loaded
machine.

Usage: python studies/actuation_delay/actuation_delay.py
       [--delays 0 0.037] [--laps 1 | --duration S]
       [--lcm-loop] [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import tempfile
import time
from pathlib import Path


def delayed_station(scenario, delay_s: float):
    """The simulated station of ``scenario`` whose plant applies the actuation ``delay_s`` late
    (same ports, named ``vehicle_station``)."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ZeroOrderHold

    from pcvfe_drake.diagrams.station import MakeVehicleStation

    station = MakeVehicleStation(scenario)
    if delay_s <= 0.0:
        return station
    period = scenario.rates.nmpc_period_s
    if delay_s >= period:
        raise ValueError(f"--delays: {delay_s} s must be below the NMPC period {period} s")
    builder = DiagramBuilder()
    inner = builder.AddNamedSystem("simulated_station", station)
    hold = builder.AddNamedSystem(
        "actuation_delay",
        ZeroOrderHold(period_sec=period, vector_size=2, offset_sec=delay_s),
    )
    builder.Connect(hold.get_output_port(), inner.GetInputPort("actuation"))
    builder.ExportInput(hold.get_input_port(), "actuation")
    for i in range(inner.num_output_ports()):
        port = inner.get_output_port(i)
        builder.ExportOutput(port, port.get_name())
    diagram = builder.Build()
    diagram.set_name("vehicle_station")
    return diagram


def lcm_loop_station(scenario):
    """The hardware station and the vehicle bridge in one diagram on one ``memq://`` bus (the
    whole LCM path: state messages checked at 100 Hz, commands published 2 ms after each NMPC
    update and applied at the bridge's next check), on the simulated clock, as fast as
    possible: the LCM loop's structural delays without any load. Exports the hardware
    station's ports and the bridge's truth (so the summary scores it)."""
    import dataclasses

    from pydrake.lcm import DrakeLcm
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.lcm import LcmBuses

    from pcvfe_drake.diagrams.station import MakeVehicleStation
    from pcvfe_drake.diagrams.vehicle_bridge import MakeVehicleBridge
    from pcvfe_drake.hardware.settings import LcmBusSettings

    hw = dataclasses.replace(
        scenario.hardware,
        lcm_buses={"default": LcmBusSettings(lcm_url="memq://")},
        bus="default",
        first_message_timeout_s=0.0,
        lateness_clock="sim",
    )
    scenario = dataclasses.replace(scenario, hardware=hw)
    buses = LcmBuses()
    buses.Add("default", DrakeLcm("memq://"))
    builder = DiagramBuilder()
    bridge = builder.AddNamedSystem("bridge", MakeVehicleBridge(scenario, lcm_buses=buses))
    station = builder.AddNamedSystem(
        "lcm_station", MakeVehicleStation(scenario, hardware=True, lcm_buses=buses)
    )
    builder.ExportInput(station.GetInputPort("actuation"), "actuation")
    for name in ("state", "image", "station_status"):
        builder.ExportOutput(station.GetOutputPort(name), name)
    for name in ("true_mu", "true_terrain", "true_state"):
        builder.ExportOutput(bridge.GetOutputPort(name), name)
    diagram = builder.Build()
    diagram.set_name("vehicle_station")
    return diagram


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_sim")
    parser.add_argument("--delays", type=float, nargs="+", default=[0.0, 0.037])
    parser.add_argument("--laps", type=float, default=1.0)
    parser.add_argument("--duration", type=float, default=None)
    parser.add_argument(
        "--lcm-loop",
        action="store_true",
        help="also run the LCM station and the bridge in one process on memq:// (no load)",
    )
    parser.add_argument("--quick", action="store_true", help="20 s instead of a lap")
    args = parser.parse_args()
    if args.quick:
        args.duration = 20.0
    from pcvfe_drake.diagrams.run_simulation import run_simulation
    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.runs.run_folder import RunFolder

    scenario = load_scenario(args.scenario)
    if args.duration is not None:
        scenario = scenario.with_run_length(laps=None, duration_s=args.duration)
    else:
        scenario = scenario.with_run_length(laps=args.laps, duration_s=None)
    scenario = dataclasses.replace(scenario)
    work = Path(tempfile.mkdtemp(prefix="actuation_delay_"))
    load0 = os.getloadavg()[0]
    print(f"load average {load0:.1f}; work folder {work}", flush=True)
    runs = []
    variants = [(f"delay_{d * 1000:.0f}ms", d) for d in args.delays]
    if args.lcm_loop:
        variants.append(("lcm_loop_memq", None))
    for name, delay in variants:
        folder = RunFolder(work / name)
        folder.prepare()
        t0 = time.perf_counter()
        station = lcm_loop_station(scenario) if delay is None else delayed_station(scenario, delay)
        result = run_simulation(
            scenario,
            folder,
            progress=False,
            write_outputs=True,
            debug_layers=False,
            controls=False,
            station=station,
        )
        s = result.summary
        estimates = [
            {
                "id": e["id"],
                "terrain": e["majority_terrain"],
                "mu_true": e["true_mu"],
                "mu_hat": e["mu_hat"],
                "rel_error": (
                    (e["mu_hat"] - e["true_mu"]) / e["true_mu"]
                    if e["true_mu"] and e["mu_hat"] is not None
                    else None
                ),
            }
            for e in s["mu_estimates"]
        ]
        runs.append(
            {
                "variant": name,
                "delay_s": delay,
                "wall_s": time.perf_counter() - t0,
                "sim_time_s": s["sim_time_s"],
                "laps": s.get("laps_completed"),
                "lap_time_s": s.get("lap_time_s"),
                "contexts": s["contexts_discovered"],
                "estimates": estimates,
            }
        )
        print(f"{name}: {s['contexts_discovered']} contexts, "
              f"lap time {s.get('lap_time_s')}", flush=True)  # fmt: skip
        for e in estimates:
            rel = "" if e["rel_error"] is None else f" ({100 * e['rel_error']:+.1f} %)"
            print(f"   context {e['id']} {e['terrain']:<13} mu_true {e['mu_true']} "
                  f"mu_hat {'no fit' if e['mu_hat'] is None else format(e['mu_hat'], '.3f')}"
                  f"{rel}", flush=True)  # fmt: skip
    result = {
        "benchmark": "actuation_delay",
        "scenario": args.scenario,
        "load_average_start": load0,
        "load_average_end": os.getloadavg()[0],
        "runs": runs,
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
