"""Per cell of a stored `pcvfe evaluate` folder: each PC-VFE source against the oracle.

    python studies/refit_cadence/compare.py RESULTS_DIR [SOURCE ...]

For each cell (scenario, world, car) and each named source (default ``pcvfe_1hz pcvfe_2hz``):
the mean speed over the oracle's, catastrophic failures, seconds above the true friction limit,
the (context, world) pairs within 0.05 after 20 s and those whose 95 % interval holds the
truth; then per source the median, worst and mean ratio over the cells the oracle drives. A
frozen study script: it reads the stored tables only.
"""

from __future__ import annotations

import argparse

import pandas as pd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("sources", nargs="*", default=["pcvfe_1hz", "pcvfe_2hz"])
    args = ap.parse_args()
    runs = pd.read_parquet(f"{args.results}/runs.parquet")
    ctx = pd.read_parquet(f"{args.results}/contexts.parquet")
    rows = []
    for cell, group in runs.groupby("scenario"):
        by = {r.source: r for r in group.itertuples()}
        oracle = by.get("oracle")
        row = {"cell": cell.replace("paper_eval-", "")}
        row["oracle_fail"] = int(oracle.failures) if oracle is not None else None
        for name in args.sources:
            r = by.get(name)
            if r is None:
                continue
            if oracle is not None:
                row[name] = round(r.mean_speed_mps / oracle.mean_speed_mps, 3)
            row[f"{name}_fail"] = int(r.failures)
            row[f"{name}_above_s"] = round(float(r.above_friction_limit) * float(r.sim_time_s), 2)
            mine = ctx[(ctx.run_id == r.run_id) & ctx.true_mu.notna()]
            settled = mine[mine.time_in_context_s >= 20.0]
            within = int((settled.abs_error_after_settle_max <= 0.05).sum())
            row[f"{name}_within"] = f"{within}/{len(settled)}"
            covered, scored = int(mine.covered_95.sum()), int(mine.covered_95.notna().sum())
            row[f"{name}_covered"] = f"{covered}/{scored}"
        rows.append(row)
    table = pd.DataFrame(rows)
    print(table.to_string(index=False))
    driven = table[table.oracle_fail == 0]
    for name in args.sources:
        if name not in driven:
            continue
        print(
            f"{name}: over the {len(driven)} cells the oracle drives median "
            f"{driven[name].median():.3f}, "
            f"worst {driven[name].min():.3f}, mean {driven[name].mean():.4f}; failures "
            f"{int(table[f'{name}_fail'].sum())} in all; most seconds above the limit "
            f"{table[f'{name}_above_s'].max()}"
        )


if __name__ == "__main__":
    main()
