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

from pcvfe_drake.contexts import density_gate
from pcvfe_drake.contexts.clustering import ContextClusterer
from pcvfe_drake.diagrams.scenario_io import scenario_from_yaml_text


def plain_quantile(kth: np.ndarray, params) -> float:
    """The gate before 2026-11-29 without its rounding floor: the plain quantile."""
    return params.gate_scale * float(np.quantile(kth, params.gate_quantile))


def few_cannot_set(kth: np.ndarray, params) -> float:
    """The variant's gate without its rounding floor (module docstring)."""
    m = kth.size
    q = min(params.gate_quantile, 1.0 - (params.gate_neighbours - 1) / m) if m else 0.0
    return params.gate_scale * float(np.quantile(kth, max(q, 0.0)))


def replay(run: Path, variant: bool) -> dict:
    density_gate._scaled_quantile = few_cannot_set if variant else plain_quantile
    scenario = scenario_from_yaml_text((run / "scenario.yaml").read_text(), str(run))
    rates = scenario.rates
    log = pd.read_parquet(run / "drive_log.parquet")
    features = [c for c in log.columns if c.startswith("f_")]
    z_all = log[features].to_numpy(float)
    times = log["t"].to_numpy(float)
    clusterer = ContextClusterer(scenario.clustering_params())
    next_recluster = rates.recluster_period_s
    ids, rows = [], []
    k = 0
    while True:
        taken = k * rates.camera_period_s
        while next_recluster <= taken + 1e-9:
            clusterer.recluster(next_recluster)
            next_recluster += rates.recluster_period_s
        row = int(np.searchsorted(times, taken + 1e-6))
        if row >= len(log):
            break
        cid, _ = clusterer.assign_frame(
            z_all[row], taken + rates.clustering_frame_offset_s, float(log["v"].iloc[row])
        )
        ids.append(cid)
        rows.append(row)
        k += 1
    ids = np.asarray(ids)
    frames = log.iloc[rows]
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
