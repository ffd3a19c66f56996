"""CPU seconds the multi-body truth spends per segment of the calibration programme.

    python studies/calibration_check/segment_cost.py VEHICLE MAPPING MU [--budget-s 120]

Drives ``calibration_drive`` (the programme at friction ``MU``) and prints, per segment, its
kind, target speed and the CPU time of its integration; stops after ``--budget-s`` CPU seconds
(a crawling drive) or at a singularity (a spun car), and prints a JSON object last.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from pcvfe_drake.vehicle import mb_truth
from pcvfe_drake.workbench import calibration_drive as cd


class _Budget(Exception):
    pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("vehicle")
    ap.add_argument("mapping")
    ap.add_argument("mu", type=float)
    ap.add_argument("--budget-s", type=float, default=120.0)
    args = ap.parse_args()
    segs = cd.programme(args.vehicle, args.mu)
    bounds = np.cumsum([0] + [int(round(s.duration_s / 0.05)) for s in segs])
    cpu = np.zeros(len(segs))
    step = [0]
    original = mb_truth.MbTruth.integrate
    start = time.process_time()

    def timed(self, *a, **kw):
        i = int(np.searchsorted(bounds, step[0], side="right") - 1)
        step[0] += 1
        t0 = time.process_time()
        out = original(self, *a, **kw)
        cpu[i] += time.process_time() - t0
        if time.process_time() - start > args.budget_s:
            raise _Budget
        return out

    mb_truth.MbTruth.integrate = timed
    ended = "completed"
    try:
        cd.calibration_drive(args.vehicle, args.mapping, args.mu)
    except _Budget:
        ended = f"stopped after {args.budget_s:g} CPU s"
    except mb_truth.MbSingularity as exc:
        ended = f"singular: {exc}"
    for i, s in enumerate(segs):
        if cpu[i] > 0:
            print(f"{i:2d} {s.kind:7s} v {s.v_mps:5.2f} m/s  cpu {cpu[i]:7.2f} s")
    print(ended)
    out = {
        "vehicle": args.vehicle,
        "mapping": args.mapping,
        "mu": args.mu,
        "ended": ended,
        "steps": step[0],
        "of_steps": int(bounds[-1]),
        "cpu_s": round(float(cpu.sum()), 2),
        "slowest_segment_cpu_s": round(float(cpu.max()), 2),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
