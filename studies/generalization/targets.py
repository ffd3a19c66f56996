"""The issue's targets on a stored run of the generalization experiment, per car and mapping.

    python studies/generalization/targets.py RESULTS_DIR

A cell is one (world, car, mapping) lap. Per variant (car and mapping) and over all: PC-VFE's
catastrophic failures (all cells, and cells the oracle completes), the oracle's; PC-VFE / oracle
mean speed over the cells the oracle completes (median, worst, and how many reach 0.90 and
0.95); the share of cells where PC-VFE beat the lookup table and the conservative fixed mu
(it completed the lap and was faster, or the other left the course and it did not); cells more
than 0.5 s above the true friction limit; (context, cell) pairs within 0.05 after a context's
first 20 s and 95 % intervals that held the truth. Then the worst cells by speed ratio. A
frozen study script: it reads the stored tables only.
Last stdout line: one JSON object with the totals.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd


def cells(folder: Path) -> pd.DataFrame:
    runs = pd.read_parquet(folder / "runs.parquet")
    ctx = pd.read_parquet(folder / "contexts.parquet")
    rows = []
    for scenario, group in runs.groupby("scenario"):
        by = {r.source: r for r in group.itertuples()}
        pc = by.get("pcvfe")
        if pc is None:
            continue
        variant, world = scenario.replace("paper_eval-", "").split("@")
        row = {"variant": variant, "world": world, "pcvfe_fail": int(pc.failures)}
        row["above_s"] = float(pc.above_friction_limit) * float(pc.sim_time_s)
        for name in ("oracle", "lookup", "fixed", "ukf"):
            other = by.get(name)
            row[f"{name}_fail"] = int(other.failures) if other is not None else np.nan
            row[f"{name}_mps"] = other.mean_speed_mps if other is not None else np.nan
        row["pcvfe_mps"] = pc.mean_speed_mps
        row["ratio"] = pc.mean_speed_mps / row["oracle_mps"]
        for name in ("lookup", "fixed"):
            if np.isnan(row[f"{name}_mps"]):
                row[f"beats_{name}"] = np.nan
                continue
            completed = row["pcvfe_fail"] == 0
            row[f"beats_{name}"] = float(
                completed and (row[f"{name}_fail"] > 0 or pc.mean_speed_mps > row[f"{name}_mps"])
            )
        mine = ctx[(ctx.run_id == pc.run_id) & ctx.true_mu.notna()]
        settled = mine[mine.time_in_context_s >= 20.0]
        row["within"] = int((settled.abs_error_after_settle_max <= 0.05).sum())
        row["settled"] = len(settled)
        row["covered"] = int(mine.covered_95.fillna(False).sum())
        row["contexts"] = len(mine)
        rows.append(row)
    return pd.DataFrame(rows)


def summarise(table: pd.DataFrame) -> dict:
    driven = table[table["oracle_fail"] == 0]
    out = {
        "cells": len(table),
        "pcvfe_failures": int(table["pcvfe_fail"].sum()),
        "pcvfe_failures_where_oracle_completes": int(driven["pcvfe_fail"].sum()),
        "oracle_failures": int(table["oracle_fail"].sum()),
        "cells_oracle_completes": len(driven),
        "ratio_median": float(driven["ratio"].median()) if len(driven) else None,
        "ratio_worst": float(driven["ratio"].min()) if len(driven) else None,
        "ratio_at_least_0_90": int((driven["ratio"] >= 0.90).sum()),
        "ratio_at_least_0_95": int((driven["ratio"] >= 0.95).sum()),
        "above_over_0_5_s": int((table["above_s"] > 0.5).sum()),
        "above_max_s": float(table["above_s"].max()),
        "within": int(table["within"].sum()),
        "settled": int(table["settled"].sum()),
        "covered": int(table["covered"].sum()),
        "contexts": int(table["contexts"].sum()),
    }
    for name in ("lookup", "fixed"):
        have = table[f"beats_{name}"].notna()
        out[f"beats_{name}"] = int(table.loc[have, f"beats_{name}"].sum())
        out[f"compared_{name}"] = int(have.sum())
    if len(driven):
        worst = driven.loc[driven["ratio"].idxmin()]
        out["worst_cell"] = f"{worst['variant']}@{worst['world']}"
    return out


def share(a: int, b: int) -> str:
    return f"{a}/{b} ({a / b:.2f})" if b else "-"


def main(folder: str) -> None:
    table = cells(Path(folder))
    print(
        "| variant | cells | PC-VFE failures (where the oracle completes) | oracle failures | "
        "speed / oracle: median, worst | >= 0.90 | >= 0.95 | beats lookup | beats fixed | "
        "> 0.5 s above | within 0.05 | 95 % intervals |"
    )
    print("|" + "---|" * 12)
    groups = [(v, g) for v, g in table.groupby("variant")] + [("all", table)]
    totals = {}
    for variant, group in groups:
        s = summarise(group)
        totals = s
        med = f"{s['ratio_median']:.3f}" if s["ratio_median"] is not None else "-"
        worst = f"{s['ratio_worst']:.3f}" if s["ratio_worst"] is not None else "-"
        n = s["cells_oracle_completes"]
        print(
            f"| {variant} | {s['cells']} | {s['pcvfe_failures']} "
            f"({s['pcvfe_failures_where_oracle_completes']}) | {s['oracle_failures']} | "
            f"{med}, {worst} | {share(s['ratio_at_least_0_90'], n)} | "
            f"{share(s['ratio_at_least_0_95'], n)} | "
            f"{share(s['beats_lookup'], s['compared_lookup'])} | "
            f"{share(s['beats_fixed'], s['compared_fixed'])} | {s['above_over_0_5_s']} "
            f"(max {s['above_max_s']:.2f} s) | {share(s['within'], s['settled'])} | "
            f"{share(s['covered'], s['contexts'])} |"
        )
    driven = table[table["oracle_fail"] == 0].sort_values("ratio")
    print("\nworst cells the oracle completes (PC-VFE / oracle speed):")
    for r in driven.head(5).itertuples():
        print(f"  {r.variant}@{r.world}: {r.ratio:.3f}")
    failed = table[table["pcvfe_fail"] > 0]
    if len(failed):
        print("PC-VFE failures:")
        for r in failed.itertuples():
            oracle = "the oracle completes it" if r.oracle_fail == 0 else "the oracle fails too"
            print(f"  {r.variant}@{r.world} ({oracle})")
    print(json.dumps(totals))


if __name__ == "__main__":
    main(sys.argv[1])
