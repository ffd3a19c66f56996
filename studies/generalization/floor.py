"""The stated-floor experiment against the oracle's laps of the generalization experiment.

    python studies/generalization/floor.py FLOOR_DIR GENERALIZATION_DIR [--car ford_escort]
        [--mapping lateral_peak]

``FLOOR_DIR``: a ``pcvfe evaluate generalization_floor`` folder (variants ``floor_above`` and
``floor_below``); ``GENERALIZATION_DIR``: a ``pcvfe evaluate generalization`` folder over the
same worlds, whose oracle laps of that car and mapping are compared (the oracle does not read
the stated floor). Per variant and source: failures and the worlds they were on, the speed over
the oracle's on the worlds the oracle completes (median, worst and its world), and the laps
more than 0.5 s above the true friction limit (with the most). A frozen study script: it reads
the stored tables only.
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("floor_dir", type=Path)
    ap.add_argument("generalization_dir", type=Path)
    ap.add_argument("--car", default="ford_escort")
    ap.add_argument("--mapping", default="lateral_peak")
    args = ap.parse_args()
    runs = pd.read_parquet(args.floor_dir / "runs.parquet")
    runs["variant"] = runs["scenario"].str.split("@").str[0].str.replace("paper_eval-", "")
    gen = pd.read_parquet(args.generalization_dir / "runs.parquet")
    cell = f"{args.car}-{args.mapping}@"
    oracle = gen[(gen["source"] == "oracle") & gen["scenario"].str.contains(cell, regex=False)]
    oracle = oracle.set_index("world")
    completes = oracle.index[oracle["failures"] == 0]
    out = {}
    for (variant, source), mine in runs.groupby(["variant", "source"]):
        mine = mine.set_index("world")
        ratio = (mine["mean_speed_mps"] / oracle["mean_speed_mps"]).reindex(completes).dropna()
        above = mine["above_friction_limit"] * mine["sim_time_s"]
        failed = sorted(mine.index[mine["failures"] > 0])
        row = {
            "laps": int(len(mine)),
            "failures": len(failed),
            "failed_worlds": failed,
            "oracle_fails_there": [int(oracle.loc[w, "failures"] > 0) for w in failed],
            "worlds_oracle_completes": int(ratio.size),
            "ratio_median": round(float(ratio.median()), 3),
            "ratio_worst": round(float(ratio.min()), 3),
            "worst_world": str(ratio.idxmin()),
            "above_over_0_5_s": int((above > 0.5).sum()),
            "above_max_s": round(float(above.max()), 2),
        }
        out[f"{variant}/{source}"] = row
        print(f"{variant:12s} {source:6s} " + ", ".join(f"{k} {v}" for k, v in row.items()))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
