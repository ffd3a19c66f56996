"""Run a stored experiment's failed laps again with the NMPC's friction clip, and compare.

    python studies/friction_clip/battery.py GEN_DIR OUT_DIR --clip drive|both
        [--sources oracle pcvfe] [--skip-worlds 119] [--jobs 2]

``GEN_DIR``: a ``pcvfe evaluate`` folder whose ``runs/<run>/scenario.yaml`` are kept (the
generalization experiment). Every run of the given sources that had a catastrophic failure is
simulated again (``pcvfe simulate SCENARIO --with OVERLAY``, the overlay setting
``nmpc.friction_clip``) into ``OUT_DIR/<clip>/<run>``, ``--jobs`` at a time; runs already there
are not run again. Prints per run the failures and mean speed before (the stored run) and
after. A frozen study script.
Last stdout line: one JSON object (failures before and after).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pandas as pd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("gen_dir", type=Path)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--clip", choices=("drive", "both"), required=True)
    ap.add_argument("--sources", nargs="+", default=["oracle", "pcvfe"])
    ap.add_argument("--skip-worlds", nargs="*", default=[], help="world seeds left out")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    runs = pd.read_parquet(args.gen_dir / "runs.parquet").set_index("run_id")
    skip = tuple(f"s{int(w):04d}" for w in args.skip_worlds)
    failed = runs[(runs["failures"] > 0) & runs["source"].isin(args.sources)]
    chosen = [r for r in failed.index if not r.split("__")[0].endswith(skip)]
    out = args.out_dir / args.clip
    out.mkdir(parents=True, exist_ok=True)
    overlay = out / "overlay.yaml"
    overlay.write_text(f"nmpc:\n  friction_clip: {args.clip}\n")

    def simulate(run_id: str) -> None:
        if (out / run_id / "summary.json").is_file():
            return
        scenario = args.gen_dir / "runs" / run_id / "scenario.yaml"
        cmd = ["pcvfe", "simulate", str(scenario), "--with", str(overlay), "--no-meshcat"]
        cmd += ["--no-progress", "--out", str(out / run_id), "--overwrite"]
        with open(out / f"{run_id}.log", "w") as log:
            subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, check=False)

    with ThreadPoolExecutor(args.jobs) as pool:
        list(pool.map(simulate, chosen))
    before = after = 0
    for run_id in chosen:
        summary = json.loads((out / run_id / "summary.json").read_text())
        n_after = len(summary.get("failure_events") or [])
        n_before = int(runs.loc[run_id, "failures"])
        before, after = before + n_before, after + n_after
        v0, v1 = runs.loc[run_id, "mean_speed_mps"], summary.get("mean_speed_mps")
        print(f"{run_id}: failures {n_before} -> {n_after}, mean speed {v0:.2f} -> {v1:.2f} m/s")
    print(json.dumps({"clip": args.clip, "runs": len(chosen), "before": before, "after": after}))


if __name__ == "__main__":
    sys.exit(main())
