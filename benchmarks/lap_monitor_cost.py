"""Cost of stopping on laps with ``Simulator.set_monitor`` (``LapMonitor``), and the stop row.

A run by laps (the monitor checks the drive log after every integrator step) against a run by
duration of the same simulated length (no monitor), alternating in one process; the figure is
the ratio of CPU time per simulated second (1.0: the monitor costs nothing measurable). Also
reports where the laps run stopped: the laps driven by the last row (the goal, not past it).

Usage: python benchmarks/lap_monitor_cost.py [--quick] [--laps 0.25] [--reps 3]
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics

from pcvfe_drake.diagrams.run_simulation import run_simulation
from pcvfe_drake.diagrams.scenario_io import load_scenario


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="0.1 laps, 2 repetitions")
    parser.add_argument("--laps", type=float, default=0.25)
    parser.add_argument("--reps", type=int, default=3)
    args = parser.parse_args()
    laps, reps = (0.1, 2) if args.quick else (args.laps, args.reps)
    base = load_scenario("paper_sim")
    base.start_s_m = 80.0
    per_s = {"laps": [], "duration": []}
    stop = None
    for rep in range(reps):
        s = run_simulation(
            base.with_run_length(laps=laps), None, progress=False, write_outputs=False
        ).summary
        stop = {"sim_time_s": s["sim_time_s"], "laps_fraction": s["laps_fraction"]}
        per_s["laps"].append(s["cpu_time_s"] / s["sim_time_s"])
        d = run_simulation(
            base.with_run_length(duration_s=s["sim_time_s"]),
            None,
            progress=False,
            write_outputs=False,
        ).summary
        per_s["duration"].append(d["cpu_time_s"] / d["sim_time_s"])
        print(
            f"rep {rep}: laps {per_s['laps'][-1] * 1e3:.1f} ms/s, "
            f"duration {per_s['duration'][-1] * 1e3:.1f} ms/s",
            flush=True,
        )
    with_monitor = statistics.median(per_s["laps"])
    without = statistics.median(per_s["duration"])
    result = {
        "laps_goal": laps,
        "stopped_at_s": stop["sim_time_s"],
        "laps_at_stop": stop["laps_fraction"],
        "cpu_ms_per_sim_s_with_monitor": round(with_monitor * 1e3, 1),
        "cpu_ms_per_sim_s_without": round(without * 1e3, 1),
        "monitor_cost_ratio": round(with_monitor / without, 3),
        "load_average_1min": os.getloadavg()[0],
        "machine": platform.processor() or platform.machine(),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
