"""``pcvfe fit`` and ``pcvfe diagnose`` on a 1-million-row drive log: time and peak memory.

The log: S-curve drives of the ST model (``synthetic_drive.s_curve_drive``, 8 m/s, 100 Hz, 0.3
Hz steering) with the documented measurement noise, up to 200 s per drive (whole steering
periods, so that each drive ends where the next starts in steering, yaw rate and slip; position
and heading jump), alternating sand (mu 0.45) and brick (mu 0.8); written as Parquet. Each
command runs in its own process (``python -m pcvfe_drake.cli``); its wall time and peak resident
memory (``ru_maxrss`` of that child, from ``os.wait4``) are measured.

Baselines in the same run, on logs whose size the caps do not touch:

* fit: a ~200,000-row log (two contexts of ~19,700 windows each: just under ``--max-windows``);
* diagnose: a 29,000-row log (under ``models.data.MAX_SAMPLES`` = 30,000: analysed whole).

The ratios (1M-row run / baseline) show what the caps bound: with them, time and memory grow
only with the reading of the log (~0.5 KB per row), not with the fit (before the caps, fit took
~4.7 KB per row and diagnose ran past 10 minutes on 2 million rows).

Usage: python benchmarks/long_log.py [--quick] [--rows N]   (--quick: 300,000 rows)
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort

SEGMENT_S = 200.0
DT_S = 0.01
STEER_PERIOD_S = 1.0 / 0.3


def make_log(rows: int, path: Path, seed: int = 0) -> int:
    """Write a drive log of about ``rows`` rows to ``path`` (Parquet); returns its row count."""
    params = ford_escort()
    n_seg = max(2, int(round(rows / (SEGMENT_S / DT_S + 1))))
    periods = max(1, int((rows / n_seg - 1) * DT_S / STEER_PERIOD_S))
    seg_s = min(SEGMENT_S, round(periods * STEER_PERIOD_S / DT_S) * DT_S)
    mus = np.where(np.arange(n_seg) % 2 == 0, 0.45, 0.8)
    t, S, U = s_curve_drive(params, mus, duration_s=seg_s, dt=DT_S, steer_freq_hz=0.3)
    rng = np.random.default_rng(seed)
    noise = MeasurementNoise()
    frames = [
        drive_frame(
            t + k * (t[-1] + DT_S),
            noise.apply(S[k], rng),
            U[k],
            terrain="sand" if k % 2 == 0 else "brick",
            mu_true=float(mus[k]),
        )
        for k in range(n_seg)
    ]
    df = pd.concat(frames, ignore_index=True)
    df.to_parquet(path, index=False)
    return len(df)


def run_command(argv: list[str]) -> dict:
    """Run ``pcvfe ARGV`` in a child process: wall time, peak memory, parsed JSON output."""
    cmd = [sys.executable, "-m", "pcvfe_drake.cli", *argv]
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read().decode(), err.read().decode()
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise SystemExit(f"pcvfe {' '.join(argv)} failed ({code}): {stderr[-2000:]}")
    return {
        "wall_s": round(wall, 2),
        "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
        "peak_mb": round(usage.ru_maxrss / 1024.0, 1),  # Linux: kilobytes
        "report": json.loads(stdout.strip().splitlines()[-1]),
        "stderr": stderr.strip().splitlines()[-3:],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="300,000 rows instead of 1,000,000")
    parser.add_argument("--rows", type=int, default=None, help="rows of the large log")
    args = parser.parse_args()
    rows = args.rows or (300_000 if args.quick else 1_000_000)
    result: dict = {"machine": platform.node(), "cpus": os.cpu_count()}
    with tempfile.TemporaryDirectory() as tmp:
        logs = {}
        for name, n in (("large", rows), ("fit_base", 200_000), ("diagnose_base", 29_000)):
            path = Path(tmp) / f"{name}.parquet"
            t0 = time.perf_counter()
            logs[name] = (path, make_log(n, path))
            print(f"{name}: {logs[name][1]} rows written in {time.perf_counter() - t0:.1f} s")
        runs = {}
        for label, log, argv in (
            ("fit", "large", ["fit", "--context-column", "terrain", "--json"]),
            ("fit_base", "fit_base", ["fit", "--context-column", "terrain", "--json"]),
            ("diagnose", "large", ["diagnose", "--json"]),
            ("diagnose_base", "diagnose_base", ["diagnose", "--json"]),
        ):
            path, n = logs[log]
            print(f"pcvfe {argv[0]} on {n} rows ...", flush=True)
            r = run_command([argv[0], str(path), *argv[1:]])
            r["rows"] = n
            print(f"  {r['wall_s']} s wall, {r['cpu_s']} s CPU, peak {r['peak_mb']} MB")
            runs[label] = r
    fit, diag = runs["fit"]["report"], runs["diagnose"]["report"]
    for label, r in runs.items():
        report = r.pop("report")
        if label.startswith("fit"):
            r["mu"] = {k: c["theta"]["mu"] for k, c in report["contexts"].items()}
            r["windows"] = {k: c["n_windows"] for k, c in report["contexts"].items()}
        else:
            r["verdict"] = {k: report["verdict"][k] for k in ("kind", "text")}
            r["selected"] = [e["name"] for e in report.get("selected", [])]
        result[label] = r
    result["fit_mu_error_max"] = max(
        abs(fit["contexts"]["sand"]["theta"]["mu"] - 0.45),
        abs(fit["contexts"]["brick"]["theta"]["mu"] - 0.8),
    )
    result["diagnose_verdict"] = diag["verdict"]["kind"]
    for cmd in ("fit", "diagnose"):
        big, base = result[cmd], result[f"{cmd}_base"]
        result[f"{cmd}_rows_ratio"] = round(big["rows"] / base["rows"], 2)
        result[f"{cmd}_time_ratio"] = round(big["wall_s"] / base["wall_s"], 2)
        result[f"{cmd}_cpu_ratio"] = round(big["cpu_s"] / max(base["cpu_s"], 1e-9), 2)
        result[f"{cmd}_memory_ratio"] = round(big["peak_mb"] / base["peak_mb"], 2)
        result[f"{cmd}_kb_per_row"] = round(big["peak_mb"] * 1024.0 / big["rows"], 3)
    print("note: timings on a shared machine; ratios are from this run")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
