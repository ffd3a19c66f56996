"""Per world and car: PC-VFE against the other sources, from stored `pcvfe evaluate` folders.

    python studies/generalization/summary.py RESULTS_DIR [RESULTS_DIR ...]

Prints one row per (scenario cell): PC-VFE / oracle mean speed, whether PC-VFE was faster than
the lookup table and the conservative fixed mu, catastrophic failures per source, PC-VFE's
seconds above the true friction limit, and its (context, world) pairs within 0.05 after 20 s
and covered by the 95 % interval; then the median and the worst cell of the PC-VFE / oracle
speed ratio over the cells the oracle drives, and the cells it fails. A frozen study script:
it reads the stored tables only.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd


def cells(folder: Path) -> pd.DataFrame:
    runs = pd.read_parquet(folder / "runs.parquet")
    ctx = pd.read_parquet(folder / "contexts.parquet")
    rows = []
    for cell, group in runs.groupby("scenario"):
        by = {r.source: r for r in group.itertuples()}
        pc = by.get("pcvfe")
        if pc is None:
            continue
        row = {"cell": cell.replace("paper_eval-", ""), "pcvfe_mps": pc.mean_speed_mps}
        for name in ("oracle", "lookup", "fixed", "ukf"):
            if name in by:
                row[f"{name}_mps"] = by[name].mean_speed_mps
                row[f"{name}_fail"] = int(by[name].failures)
        row["ratio"] = pc.mean_speed_mps / row["oracle_mps"] if "oracle_mps" in row else None
        row["pcvfe_fail"] = int(pc.failures)
        row["above_s"] = float(pc.above_friction_limit) * float(pc.sim_time_s)
        mine = ctx[(ctx.run_id == pc.run_id) & ctx.true_mu.notna()]
        settled = mine[mine.time_in_context_s >= 20.0]
        row["within"] = f"{int((settled.abs_error_after_settle_max <= 0.05).sum())}/{len(settled)}"
        row["covered"] = f"{int(mine.covered_95.fillna(False).sum())}/{len(mine)}"
        rows.append(row)
    return pd.DataFrame(rows)


def main(folders: list[str]) -> None:
    table = pd.concat([cells(Path(f)) for f in folders], ignore_index=True)
    pd.set_option("display.width", 200)
    print(table.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    # A world the oracle itself leaves has no oracle speed to compare with.
    driven = table[table["ratio"].notna() & (table.get("oracle_fail", 0) == 0)]
    if not driven.empty:
        worst = driven.loc[driven["ratio"].idxmin()]
        print(
            f"\nPC-VFE / oracle speed over the {len(driven)} cells the oracle drives: median "
            f"{driven['ratio'].median():.3f}, worst {worst['ratio']:.3f} ({worst['cell']})"
        )
    if "oracle_fail" in table:
        left = table.loc[table["oracle_fail"] > 0, "cell"].tolist()
        if left:
            print(f"cells the oracle itself fails: {', '.join(left)}")
    for name in ("lookup", "fixed"):
        if f"{name}_mps" in table:
            faster = (table["pcvfe_mps"] > table[f"{name}_mps"]).sum()
            print(f"PC-VFE faster than {name}: {faster} of {table[f'{name}_mps'].notna().sum()}")
    print(
        f"PC-VFE failures: {table['pcvfe_fail'].sum()}; most seconds above the limit: "
        f"{table['above_s'].max():.2f}"
    )


if __name__ == "__main__":
    main(sys.argv[1:])
