"""PC-VFE against the oracle over several `pcvfe evaluate` folders of generated worlds.

    python studies/fresh_worlds/summary.py DIR[:SOURCE][@ORACLE_DIR] [...] [--worst 3]

``SOURCE`` names the PC-VFE source in that folder (default ``pcvfe``; an older folder may hold
today's default under another name); ``ORACLE_DIR`` a folder of the same worlds whose oracle
runs are compared (default: the oracle in ``DIR``; the oracle's laps do not depend on the
estimator's code, so a PC-VFE-only run of changed code reuses them). Prints one row per
(world, car) cell: the PC-VFE / oracle mean speed, failures and seconds above the true
friction limit of both, PC-VFE's contexts within 0.05 after 20 s and covered by their 95 %
interval; then, over the cells the oracle drives, the median, the worst and the median of each
world's worst car; and for the ``--worst`` cells each terrain visit: its true mu, how long it
lasted, the seconds lost to the oracle at the same arc length (in all and in the visit's first
8 s) and the handed mu's 10th / 50th / 90th percentiles. A frozen study script: it reads the
stored tables and drive logs only.
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.evaluation.entry_latency import terrain_lag


def cells(folder: Path, source: str, oracle_folder: Path | None = None) -> pd.DataFrame:
    runs = pd.read_parquet(folder / "runs.parquet")
    ctx = pd.read_parquet(folder / "contexts.parquet")
    oracle_folder = oracle_folder or folder
    oracles = pd.read_parquet(oracle_folder / "runs.parquet")
    oracles = {r.scenario: r for r in oracles[oracles.source == "oracle"].itertuples()}
    rows = []
    for cell, group in runs.groupby("scenario"):
        by = {r.source: r for r in group.itertuples()}
        pc, oracle = by.get(source), oracles.get(cell)
        if pc is None or oracle is None:
            continue
        mine = ctx[(ctx.run_id == pc.run_id) & ctx.true_mu.notna()]
        settled = mine[mine.time_in_context_s >= 20.0]
        rows.append(
            {
                "cell": cell.replace("paper_eval-", ""),
                "world": str(pc.world),
                "ratio": pc.mean_speed_mps / oracle.mean_speed_mps,
                "pcvfe_fail": int(pc.failures),
                "oracle_fail": int(oracle.failures),
                "pcvfe_above_s": float(pc.above_friction_limit) * float(pc.sim_time_s),
                "oracle_above_s": float(oracle.above_friction_limit) * float(oracle.sim_time_s),
                "within": int((settled.abs_error_after_settle_max <= 0.05).sum()),
                "settled": len(settled),
                "covered": int(mine.covered_95.fillna(False).sum()),
                "contexts": len(mine),
                "run": folder / "runs" / pc.run_id,
                "reference": oracle_folder / "runs" / oracle.run_id,
            }
        )
    return pd.DataFrame(rows)


def visits(run: Path, reference: Path) -> list[dict]:
    log = pd.read_parquet(run / "drive_log.parquet")
    lag = terrain_lag(run, reference, (8.0,))["visits"]
    out = []
    for v in lag:
        rows = log[(log.t >= v["t_enter_s"]) & (log.t <= v["t_enter_s"] + v["run_s"])]
        handed = rows["mu_hat"].to_numpy(float)
        out.append(
            {
                "terrain": v["terrain"],
                "mu": float(rows["mu_true"].iloc[0]) if len(rows) else float("nan"),
                "enter_s": v["t_enter_s"],
                "visit_s": v["run_s"],
                "lost_s": v["lag_s"],
                "lost_first_8_s": v["lag_first_s"]["8"],
                "handed_p10_p50_p90": [
                    round(float(q), 3) for q in np.nanpercentile(handed, [10, 50, 90])
                ],
            }
        )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", help="DIR, DIR:SOURCE, DIR@ORACLE_DIR")
    ap.add_argument("--worst", type=int, default=3, help="cells whose visits are printed")
    args = ap.parse_args()
    parts = []
    for spec in args.folders:
        spec, _, oracle = spec.partition("@")
        folder, _, source = spec.partition(":")
        parts.append(cells(Path(folder), source or "pcvfe", Path(oracle) if oracle else None))
    table = pd.concat(parts, ignore_index=True)
    pd.set_option("display.width", 220)
    shown = table.drop(columns=["run", "reference"])
    print(shown.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    driven = table[table.oracle_fail == 0]
    per_world = driven.groupby("world")["ratio"].min()
    worst = driven.loc[driven["ratio"].idxmin()]
    print(
        f"\n{table.world.nunique()} worlds, {len(table)} cells; over the {len(driven)} cells the "
        f"oracle drives ({driven.world.nunique()} worlds): PC-VFE / oracle speed median "
        f"{driven.ratio.median():.3f}, worst {worst.ratio:.3f} ({worst.cell}); each world's "
        f"worst car: median {per_world.median():.3f}; cells at 0.90 or more "
        f"{int((driven.ratio >= 0.90).sum())}/{len(driven)}"
    )
    print(
        f"PC-VFE failures {int(table.pcvfe_fail.sum())} (the oracle "
        f"{int(table.oracle_fail.sum())}); cells above the limit over 0.5 s: PC-VFE "
        f"{int((table.pcvfe_above_s > 0.5).sum())}, "
        f"the oracle {int((table.oracle_above_s > 0.5).sum())}; within 0.05 after 20 s "
        f"{int(table.within.sum())}/{int(table.settled.sum())}; covered "
        f"{int(table.covered.sum())}/{int(table.contexts.sum())}"
    )
    detail = {}
    for row in driven.nsmallest(args.worst, "ratio").itertuples():
        print(f"\n{row.cell}: {row.ratio:.3f} of the oracle")
        detail[row.cell] = visits(row.run, row.reference)
        for v in detail[row.cell]:
            print(
                f"  {v['terrain']:14s} mu {v['mu']:.2f}  at {v['enter_s']:6.1f} s for "
                f"{v['visit_s']:5.1f} s: lost {v['lost_s']:5.2f} s ({v['lost_first_8_s']:5.2f} in "
                f"its first 8 s), handed p10/p50/p90 {v['handed_p10_p50_p90']}"
            )
    print(
        json.dumps(
            {
                "worlds": int(table.world.nunique()),
                "cells": len(table),
                "cells_oracle_drives": len(driven),
                "median": round(float(driven.ratio.median()), 4),
                "worst": round(float(worst.ratio), 4),
                "worst_cell": worst.cell,
                "median_of_world_worst": round(float(per_world.median()), 4),
                "at_least_0_90": int((driven.ratio >= 0.90).sum()),
                "pcvfe_failures": int(table.pcvfe_fail.sum()),
                "oracle_failures": int(table.oracle_fail.sum()),
                "pcvfe_above_over_0_5": int((table.pcvfe_above_s > 0.5).sum()),
                "oracle_above_over_0_5": int((table.oracle_above_s > 0.5).sum()),
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
