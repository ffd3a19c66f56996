"""Would other OSQP settings make the NMPC's solves cheaper? Record every QP of a drive, then
solve the same sequence again with other settings.

Drives ``pcvfe simulate SCENARIO --duration S --estimator oracle`` in this process with the
NMPC's solver wrapped, recording each update's QP data (the values written into the fixed
sparsity patterns, the bounds, the warm start) and its solution. Then for each setting it sets
up a fresh solver on the same patterns and solves the recorded sequence in order, as the
controller does (update, warm start, solve), and prints the CPU time, the iterations and the
largest difference of a solution from the recorded one; one JSON object last.

Usage: python studies/nmpc_osqp_settings/replay.py [--scenario paper_eval] [--with FILE]
           [--duration 60] [--quick]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import osqp
import scipy.sparse as sp

from pcvfe_drake.cli import main as pcvfe_main
from pcvfe_drake.control import nmpc

SETTINGS = [{}, {"alpha": 1.7}, {"alpha": 1.8}, {"alpha": 1.9}, {"adaptive_rho_interval": 0},
            {"check_termination": 10}]  # fmt: skip


class _Recorder:
    """Stands in for the controller's OSQP object for one update and records what it is given."""

    def __init__(self, solver, records: list):
        self.solver, self.records, self.record = solver, records, {}

    def update(self, **kw):
        self.record["update"] = {k: np.array(v) for k, v in kw.items()}
        return self.solver.update(**kw)

    def warm_start(self, **kw):
        self.record["warm"] = {k: np.array(v) for k, v in kw.items()}
        return self.solver.warm_start(**kw)

    def solve(self, **kw):
        result = self.solver.solve(**kw)
        self.record["x"] = np.array(result.x)
        self.records.append(self.record)
        return result

    def update_settings(self, **kw):
        return self.solver.update_settings(**kw)


def record(args) -> tuple[list, dict]:
    records: list = []
    seen: dict = {}
    real_step = nmpc.NmpcController.step

    def step(self, x, theta, memory):
        seen["controller"] = self
        solver = self._solver
        self._solver = _Recorder(solver, records)
        try:
            return real_step(self, x, theta, memory)
        finally:
            self._solver = solver

    nmpc.NmpcController.step = step
    try:
        with tempfile.TemporaryDirectory() as tmp:
            extra = ["--with", str(args.with_file)] if args.with_file else []
            pcvfe_main(["simulate", args.scenario, *extra, "--duration", str(args.duration),
                        "--estimator", "oracle", "--no-meshcat", "--no-progress",
                        "--out", str(Path(tmp) / "run")])  # fmt: skip
    finally:
        nmpc.NmpcController.step = real_step
    return records, seen["controller"]


def replay(records: list, ctrl, over: dict) -> dict:
    settings = {**ctrl.osqp_settings(), **over}
    first = records[0]["update"]
    P = sp.csc_matrix((first["Px"], ctrl._P.indices, ctrl._P.indptr), shape=ctrl._P.shape)
    A = sp.csc_matrix((first["Ax"], ctrl._A.indices, ctrl._A.indptr), shape=ctrl._A.shape)
    solver = osqp.OSQP()
    solver.setup(P, first["q"], A, first["l"], first["u"], **settings)
    iterations, gaps = [], []
    c0 = time.thread_time()
    for r in records:
        solver.update(**r["update"])
        solver.warm_start(**r["warm"])
        result = solver.solve(raise_error=False)
        iterations.append(result.info.iter)
        gaps.append(float(np.max(np.abs(result.x - r["x"]))))
    return {
        "cpu_s": round(time.thread_time() - c0, 3),
        "iterations_mean": round(float(np.mean(iterations)), 1),
        "iterations_p50": float(np.median(iterations)),
        "iterations_p99": float(np.percentile(iterations, 99)),
        "largest_solution_difference": float(np.max(gaps)),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="paper_eval")
    ap.add_argument("--with", dest="with_file", type=Path, help="a scenario file on top")
    ap.add_argument("--duration", type=float, default=60.0, help="driven seconds")
    ap.add_argument("--quick", action="store_true", help="10 s of driving")
    args = ap.parse_args(argv)
    if args.quick:
        args.duration = 10.0
    records, ctrl = record(args)
    print(f"{len(records)} QPs recorded")
    out = {}
    for over in SETTINGS:
        name = ", ".join(f"{k}={v}" for k, v in over.items()) or "shipped"
        out[name] = replay(records, ctrl, over)
        print(f"  {name:28s} {out[name]}")
    print(json.dumps({"study": "nmpc_osqp_settings", "scenario": args.scenario,
                      "with": str(args.with_file or ""), "settings": out}))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
