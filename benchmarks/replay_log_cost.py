"""What a replayable drive log costs, and what a replay of the default log gives.

``pcvfe replay`` reruns perception and estimation on a run folder. It reproduces the run to
the last bit only when the run logged every fitter sample (``rates.log_period_s`` =
``fitter_sample_period_s``, 100 Hz) and saved every camera frame (``rates.frame_log_period_s``
= ``camera_period_s``); the defaults log at 20 Hz and save a frame every 2 s. This benchmark runs
the scenario both ways (``simulate`` as a subprocess, no Meshcat), replays each run, and
reports for each: the run's disk use (drive log, frames) per simulated minute, its CPU time per
simulated second, the replay's CPU time, and how far the replay's estimates and contexts are
from the original's.

Usage: python benchmarks/replay_log_cost.py [--scenario paper_sim] [--duration 40] [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

REPLAYABLE = "rates:\n  log_period_s: 0.01\n  frame_log_period_s: 0.1\n"


def pcvfe(*args: str) -> list[str]:
    return [sys.executable, "-m", "pcvfe_drake.cli", *args]


def timed(command: list[str], cwd: Path) -> float:
    """CPU seconds (user + system) of ``command`` and its children."""
    before = os.times()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, cwd=cwd)
    after = os.times()
    return (after.children_user - before.children_user) + (
        after.children_system - before.children_system
    )


def folder_bytes(folder: Path, pattern: str) -> int:
    return sum(p.stat().st_size for p in folder.glob(pattern) if p.is_file())


def compare(original: Path, replayed: Path) -> dict:
    """How the replay's drive log differs from the original's."""
    a = pd.read_csv(original / "drive_log.csv")
    b = pd.read_csv(replayed / "drive_log.csv")
    n = min(len(a), len(b))
    a, b = a.iloc[:n], b.iloc[:n]
    out = {"rows": n}
    for col in ("mu_hat", "context"):
        x, y = a[col].to_numpy(float), b[col].to_numpy(float)
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        out[f"{col}_rows_equal_share"] = float(same.mean())
        if col == "mu_hat":
            out["mu_hat_max_abs_diff"] = float(np.nanmax(np.abs(x - y)))
    sa = json.loads((original / "summary.json").read_text())
    sb = json.loads((replayed / "summary.json").read_text())
    out["contexts"] = [sa["contexts_discovered"], sb["contexts_discovered"]]
    out["final_mu_hat"] = [
        [None if e["mu_hat"] is None else round(e["mu_hat"], 4) for e in sa["mu_estimates"]],
        [None if e["mu_hat"] is None else round(e["mu_hat"], 4) for e in sb["mu_estimates"]],
    ]
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_sim")
    parser.add_argument("--duration", type=float, default=40.0)
    parser.add_argument("--quick", action="store_true", help="12 s")
    args = parser.parse_args()
    if args.quick:
        args.duration = 12.0
    work = Path(tempfile.mkdtemp(prefix="replay_cost_"))
    (work / "replayable.yaml").write_text(REPLAYABLE)
    load0 = os.getloadavg()[0]
    print(f"load average {load0:.1f}; work folder {work}", flush=True)
    result = {"benchmark": "replay_log_cost", "scenario": args.scenario, "load_average": load0}
    for name, extra in (("default", []), ("replayable", ["--with", str(work / "replayable.yaml")])):
        run = work / name
        t0 = time.perf_counter()
        cpu = timed(
            pcvfe(
                "simulate",
                args.scenario,
                *extra,
                "--duration",
                str(args.duration),
                "--no-meshcat",
                "--no-progress",
                "--out",
                str(run),
            ),
            work,
        )
        wall = time.perf_counter() - t0
        replay_cpu = timed(
            pcvfe("replay", str(run), "--out", str(work / f"{name}_replay"), "--no-progress"),
            work,
        )
        minutes = args.duration / 60.0
        log_bytes = folder_bytes(run, "drive_log.*")
        frame_bytes = folder_bytes(run / "frames", "*")
        result[name] = {
            "simulate_cpu_s_per_sim_s": cpu / args.duration,
            "simulate_wall_s": wall,
            "replay_cpu_s_per_sim_s": replay_cpu / args.duration,
            "drive_log_mb_per_min": log_bytes / 1e6 / minutes,
            "frames_mb_per_min": frame_bytes / 1e6 / minutes,
            "frames": len(list((run / "frames").glob("*"))),
            "replay_vs_original": compare(run, work / f"{name}_replay"),
        }
        r = result[name]
        print(
            f"{name}: simulate {r['simulate_cpu_s_per_sim_s']:.2f} CPU-s per sim-s, replay "
            f"{r['replay_cpu_s_per_sim_s']:.2f}; drive log {r['drive_log_mb_per_min']:.2f} MB/min,"
            f" frames {r['frames_mb_per_min']:.2f} MB/min; replay mu_hat equal on "
            f"{100 * r['replay_vs_original']['mu_hat_rows_equal_share']:.1f} % of rows, "
            f"max diff {r['replay_vs_original']['mu_hat_max_abs_diff']:.4f}",
            flush=True,
        )
    d, r = result["default"], result["replayable"]
    result["ratios_replayable_over_default"] = {
        "simulate_cpu": r["simulate_cpu_s_per_sim_s"] / d["simulate_cpu_s_per_sim_s"],
        "disk": (r["drive_log_mb_per_min"] + r["frames_mb_per_min"])
        / (d["drive_log_mb_per_min"] + d["frames_mb_per_min"]),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
