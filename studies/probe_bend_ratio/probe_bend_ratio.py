"""The probe's bend ratio on saved closed-loop runs: how far along the tyre curve the car worked.

For every run folder given (``pcvfe simulate`` output: ``drive_log.csv`` or ``.parquet`` with
the measured states, the handed ``mu_hat``, ``C_Sf_hat``, ``C_Sr_hat``, the terrain and its true
mu), the log is cut into windows of ``--window`` seconds (3 s: one bend of the paper's slalom at
5-6 m/s, the probe's ``probe_hold_s``) and each window's bend ratio per axle is computed as the
probe computes it (``pcvfe_drake.estimation.probe.bend_ratios``, with the handed small-slip
stiffness ``mu_hat * C_S`` and the probe's ``probe_min_force`` 0.1 g); windows on one terrain with
one context id and at >= 3 m/s are kept. Each row: the terrain, its true mu, the handed mu, the
lateral friction used (95th percentile of ``|v (psi_dot + beta_dot)| / g``), the two ratios and
the handed mu over the true one. The summary groups the windows by terrain and that quotient:
the ratio the tyres showed where the probe handed about the truth (0.9-1.1) is what
``probe_linear_ratio`` is compared with (docs/fitting.md, "Exploration").

The log is at its logging rate (20 Hz in the shipped scenarios), not the fitter's 100 Hz, so a
window has a fifth of the live samples (the probe's 1 s minimum of samples at force still holds).

Usage: python studies/probe_bend_ratio/probe_bend_ratio.py
       [RUN_DIR ...] [--window 3] [--json-only] [--quick]
           [--scenario S]
Without run folders it makes one: ``pcvfe simulate SCENARIO --seed 0`` (default
``paper_eval_effects``; one lap, 1-3 min; ``--quick``: its first 60 s, sand and concrete).
Prints a table per run and one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.estimation.effect_fit import friction_used
from pcvfe_drake.estimation.probe import bend_ratios
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import STATE_NAMES

MIN_FORCE = 0.1
"""The probe's ``probe_min_force`` [g]."""
BANDS = ((0.0, 0.9), (0.9, 1.1), (1.1, 1.3), (1.3, 10.0))
"""Groups of handed mu / true mu."""


def make_run(out: Path, scenario: str, duration_s: float | None = None) -> Path:
    """One ``pcvfe simulate`` of ``scenario``, seed 0, no Meshcat, into ``out`` (``duration_s``:
    only its first seconds; None: the scenario's length)."""
    from pcvfe_drake.cli import main as pcvfe

    cmd = ["simulate", scenario, "--seed", "0", "--no-meshcat", "--out", str(out)]
    cmd += ["--duration", f"{duration_s:g}"] if duration_s is not None else []
    print("making a run: pcvfe " + " ".join(cmd), flush=True)
    if pcvfe(cmd) != 0:
        raise SystemExit("pcvfe simulate failed")
    return out


def _log(run: Path) -> pd.DataFrame:
    for name in ("drive_log.parquet", "drive_log.csv"):
        if (run / name).exists():
            return (pd.read_parquet if name.endswith("parquet") else pd.read_csv)(run / name)
    raise FileNotFoundError(f"{run}: no drive_log.parquet or drive_log.csv (a pcvfe simulate run)")


def windows(run: Path, window_s: float) -> list[dict]:
    """One row per kept window of ``run`` (see the module docstring)."""
    vp = ford_escort()
    log = _log(run)
    t = log["t"].to_numpy(float)
    x = log[list(STATE_NAMES)].to_numpy(float)
    stiff = np.c_[log["mu_hat"] * log["C_Sf_hat"], log["mu_hat"] * log["C_Sr_hat"]]
    rows = []
    for t0 in np.arange(t[0], t[-1], window_s):
        sel = np.flatnonzero((t >= t0) & (t < t0 + window_s))
        if sel.size < 10:
            continue
        terrain, ctx = log["terrain"].iloc[sel], log["context"].iloc[sel]
        if terrain.nunique() != 1 or ctx.nunique() != 1 or ctx.iloc[0] < 0:
            continue
        if np.mean(x[sel, 3]) < 3.0:
            continue
        k = np.median(stiff[sel], axis=0)
        bf, br = bend_ratios(t[sel], x[sel], vp.lf, vp.lr, vp.I_z / vp.m, k, MIN_FORCE)
        if not (math.isfinite(bf) or math.isfinite(br)):
            continue
        handed = float(np.median(log["mu_hat"].iloc[sel]))
        true = float(log["mu_true"].iloc[sel[-1]])
        rows.append(
            {
                "run": run.name,
                "t_s": round(float(t0), 2),
                "terrain": str(terrain.iloc[0]),
                "mu_true": true,
                "mu_handed": round(handed, 4),
                "used": round(friction_used(t[sel], x[sel], lateral_only=True), 4),
                "bend_front": round(bf, 3) if math.isfinite(bf) else None,
                "bend_rear": round(br, 3) if math.isfinite(br) else None,
                "handed_over_true": round(handed / true, 3),
            }
        )
    return rows


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", type=Path, help="pcvfe simulate run folders")
    ap.add_argument("--window", type=float, default=3.0, help="window length [s]")
    ap.add_argument("--json-only", action="store_true")
    ap.add_argument("--quick", action="store_true", help="without runs: a 60 s run")
    ap.add_argument("--scenario", default="paper_eval", help="without runs: this one")
    args = ap.parse_args(argv)
    if not args.runs:
        with tempfile.TemporaryDirectory(prefix="bend_ratio_") as tmp:
            made = make_run(Path(tmp) / "run", args.scenario, 60.0 if args.quick else None)
            rest = ["--window", str(args.window)] + (["--json-only"] if args.json_only else [])
            return main([str(made), *rest])
    start = time.process_time()
    rows = [r for run in args.runs for r in windows(run, args.window)]
    if not args.json_only:
        for r in rows:
            print(
                f"{r['run']:20s} t {r['t_s']:6.1f} {r['terrain']:13s} mu {r['mu_true']:.2f} "
                f"handed {r['mu_handed']:.2f} used {r['used']:.2f} bend "
                f"{r['bend_front']} / {r['bend_rear']}"
            )
    bands = []
    for (lo, hi), terrain in (
        (b, name) for name in sorted({r["terrain"] for r in rows}) for b in BANDS
    ):
        sel = [r for r in rows if lo <= r["handed_over_true"] < hi and r["terrain"] == terrain]
        if not sel:
            continue
        worst = [max(v for v in (r["bend_front"], r["bend_rear"]) if v is not None) for r in sel]
        bands.append(
            {
                "terrain": terrain,
                "handed_over_true": [lo, hi],
                "windows": len(sel),
                "bend_max_axle_q10_q50_q90": (
                    [round(float(v), 3) for v in np.quantile(worst, [0.1, 0.5, 0.9])]
                    if worst
                    else None
                ),
            }
        )
    out = {
        "benchmark": "probe_bend_ratio",
        "runs": [str(r) for r in args.runs],
        "window_s": args.window,
        "windows": len(rows),
        "by_handed_over_true": bands,
        "cpu_s": round(time.process_time() - start, 2),
    }
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
