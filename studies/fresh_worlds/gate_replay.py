"""The context clustering replayed open-loop from stored drive logs, with the plain-quantile
outlier gate and with a gate that no group smaller than ``gate_neighbours`` can set.

A context's gate is ``gate_scale`` times the ``gate_quantile`` (0.99) of its members' own k-th-
neighbour distances. Of fewer than about 100 members that quantile is the largest one or two
values: a lone stray sets it (studies/fresh_worlds/README.md, world 452). The variant takes the
quantile at ``min(gate_quantile, 1 - (k - 1) / M)`` for M members, k = ``gate_neighbours``: the
k - 1 largest distances never set the gate, as a group of fewer than k members cannot pass a
frame by nearness either (``density_gate.detach_pockets``). Nothing else changes; for a context
of 200 members or more it is the plain gate.

Per run (the run's own scenario, its logged features, open-loop: the car's path is the logged
one), for each gate: seconds of frames given a context whose majority true terrain (over the
replayed lap) is another terrain, of those the seconds where that context's terrain has more
friction than the frame's by more than 0.05 (what the handing could hand too high), and seconds
of noise frames. The plain gate's ids are checked against the logged ones (laps driven with it).

    python studies/fresh_worlds/gate_replay.py RESULTS_DIR[:SOURCE] [...] [--workers 2]

Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
from cluster_gate import plain_quantile, replay_clustering  # this folder's (the script's path)

from pcvfe_drake.contexts import density_gate

# The gate as shipped now (``density_gate._scaled_quantile``: the quantile at
# ``min(gate_quantile, 1 - (k - 1) / M)``), kept before the replays swap the function.
few_cannot_set = density_gate._scaled_quantile


def replay(run: Path, variant: bool) -> dict:
    density_gate._scaled_quantile = few_cannot_set if variant else plain_quantile
    scenario, _, frames = replay_clustering(run)
    rates = scenario.rates
    ids = frames["id"].to_numpy(int)
    terrain = frames["terrain"].astype(str).to_numpy()
    mu = frames["mu_true"].to_numpy(float)
    dt = rates.camera_period_s
    confused = risky = 0.0
    for cid in np.unique(ids[ids >= 0]):
        mine = ids == cid
        names, counts = np.unique(terrain[mine], return_counts=True)
        major = names[np.argmax(counts)]
        major_mu = float(np.median(mu[mine & (terrain == major)]))
        other = mine & (terrain != major)
        confused += dt * other.sum()
        risky += dt * (other & (major_mu > mu + 0.05)).sum()
    logged = frames["context"].to_numpy(int)
    return {
        "run": run.name,
        "frames": int(ids.size),
        "confused_s": round(confused, 2),
        "too_grippy_s": round(risky, 2),
        "noise_s": round(dt * float((ids < 0).sum()), 2),
        "ids_differing_from_log": int((ids != logged).sum()),
    }


def both(run: Path) -> tuple[dict, dict]:
    return replay(run, False), replay(run, True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="*", help="RESULTS_DIR or RESULTS_DIR:SOURCE")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    if not args.folders:
        ap.error("give at least one `pcvfe evaluate` results folder")
    runs = []
    for spec in args.folders:
        folder, _, source = spec.partition(":")
        table = pd.read_parquet(Path(folder) / "runs.parquet")
        for run_id in table.loc[table["source"] == (source or "pcvfe"), "run_id"]:
            runs.append(Path(folder) / "runs" / run_id)
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(both, runs))
    rows = []
    for plain, variant in results:
        rows.append(
            {
                "run": plain["run"].replace("paper_eval-", "")[:60],
                "confused_s": plain["confused_s"],
                "confused_s_variant": variant["confused_s"],
                "too_grippy_s": plain["too_grippy_s"],
                "too_grippy_s_variant": variant["too_grippy_s"],
                "noise_s": plain["noise_s"],
                "noise_s_variant": variant["noise_s"],
                "ids_differing_from_log": plain["ids_differing_from_log"],
            }
        )
    table = pd.DataFrame(rows)
    pd.set_option("display.width", 220)
    print(table.to_string(index=False))
    sums = table.drop(columns=["run"]).sum().round(2).to_dict()
    worse = int((table["too_grippy_s_variant"] > table["too_grippy_s"] + 1e-9).sum())
    better = int((table["too_grippy_s_variant"] < table["too_grippy_s"] - 1e-9).sum())
    print(
        f"\n{len(table)} laps; totals {sums}; too grippy: variant better on {better}, "
        f"worse on {worse}"
    )
    print(
        json.dumps({"laps": len(table), **sums, "variant_better": better, "variant_worse": worse})
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
