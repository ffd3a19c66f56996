"""Replay a run's context clustering from its drive log and show one context's outlier gate.

The drive log holds every camera frame's features (the row after a frame carries them), so the
clustering (`ContextClusterer`: per-frame assignment, the periodic re-clustering, the novelty
trigger) can be run again outside the diagram. The script replays up to ``--at`` seconds,
prints each frame's id and how it got it (`gate`, `continued`, `held`, `noise`, ...) from
``--from`` on, checks every id against the logged one, and then describes context ``--context``
as the gate index holds it: its members' terrains (from the log's truth) and times, their own
leave-one-out k-th-neighbour distances (the gate is `gate_scale` times their `gate_quantile`),
and the k-th-neighbour distance of the next frames of ``--terrain`` to those members.

    python studies/fresh_worlds/cluster_gate.py RUN_DIR --from 78.8 --at 80.5 --context 0
        [--terrain concrete]

Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.contexts import density_gate
from pcvfe_drake.contexts.clustering import ContextClusterer
from pcvfe_drake.contexts.density_gate import kth_member_distances
from pcvfe_drake.diagrams.scenario_io import scenario_from_yaml_text


def plain_quantile(kth: np.ndarray, params) -> float:
    """The outlier gate before 2026-11-29 (without its rounding floor): ``gate_scale`` times the
    plain ``gate_quantile`` of the members' k-th-neighbour distances, whatever their number.
    Laps driven before then replay to their logged ids only with it (``--gate plain``)."""
    return params.gate_scale * float(np.quantile(kth, params.gate_quantile))


def replay_clustering(run: Path, until_s: float = math.inf):
    """The lap's clustering in ``run`` replayed from its drive log up to ``until_s`` [s]:
    ``(scenario, clusterer, frames)``, ``frames`` the log's rows holding each frame with the
    replayed ``id``, how the frame got it (``evidence``) and whether it triggered a kept
    re-clustering (``triggered``)."""
    scenario = scenario_from_yaml_text((run / "scenario.yaml").read_text(), str(run))
    rates = scenario.rates
    log = pd.read_parquet(run / "drive_log.parquet")
    z_all = log[[c for c in log.columns if c.startswith("f_")]].to_numpy(float)
    times = log["t"].to_numpy(float)
    clusterer = ContextClusterer(scenario.clustering_params())
    next_recluster = rates.recluster_period_s
    rows, ids, evidence, triggered = [], [], [], []
    k = 0
    while True:
        taken = k * rates.camera_period_s
        t_assign = taken + rates.clustering_frame_offset_s
        while next_recluster <= taken + 1e-9:
            clusterer.recluster(next_recluster)
            next_recluster += rates.recluster_period_s
        row = int(np.searchsorted(times, taken + 1e-6))
        if t_assign > until_s or row >= len(log):
            break
        cid, kept = clusterer.assign_frame(z_all[row], t_assign, float(log["v"].iloc[row]))
        rows.append(row)
        ids.append(cid)
        evidence.append(clusterer.last_evidence)
        triggered.append(kept)
        k += 1
    frames = log.iloc[rows].assign(
        t_assign=np.arange(len(rows)) * rates.camera_period_s + rates.clustering_frame_offset_s,
        id=np.asarray(ids, dtype=int),
        evidence=evidence,
        triggered=triggered,
    )
    return scenario, clusterer, frames


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, nargs="?", default=None, help="a run folder")
    ap.add_argument("--from", dest="t_from", type=float, default=0.0)
    ap.add_argument("--at", type=float, default=10.0, help="replay up to this time [s]")
    ap.add_argument("--context", type=int, default=0)
    ap.add_argument("--terrain", default=None, help="frames whose distance to the members is shown")
    ap.add_argument(
        "--gate",
        choices=("current", "plain"),
        default="current",
        help="the outlier gate to replay with: the shipped one, or the plain quantile the laps "
        "before 2026-11-29 were driven with",
    )
    args = ap.parse_args()
    if args.run is None:
        ap.error("give a run folder (RUN_DIR with scenario.yaml and drive_log.parquet)")
    if args.gate == "plain":
        density_gate._scaled_quantile = plain_quantile
    scenario, clusterer, frames = replay_clustering(args.run, args.at)
    params = scenario.clustering_params()
    rates = scenario.rates
    log = pd.read_parquet(args.run / "drive_log.parquet")
    features = [c for c in log.columns if c.startswith("f_")]
    times = log["t"].to_numpy(float)
    mismatches = int((frames["id"] != frames["context"]).sum())
    for f in frames[frames["t_assign"] >= args.t_from].itertuples():
        print(
            f"{f.t_assign:8.3f} s  {f.terrain:14s} id {f.id:3d} (logged {f.context:3d})  "
            f"{f.evidence}{'  re-clustered' if f.triggered else ''}"
        )
    index = clusterer._index  # the gate index: members and gates of the active contexts
    if args.context not in index.bounds:
        print(f"context {args.context} is not active at {args.at} s")
        return 1
    s, e = index.bounds[args.context]
    members = index.x[s:e]
    kth = kth_member_distances(members, params.gate_neighbours)
    gate = float(np.sqrt(index.gate_sq[args.context]))
    # The members' rows of the store (same order as the index: stored order within a context).
    n = clusterer._x.shape[0]
    rows = np.flatnonzero(clusterer._used[:n] & (clusterer._label[:n] == args.context))
    member_t = clusterer._t[rows]
    terrain = [
        str(log["terrain"].iloc[int(np.searchsorted(times, t - rates.clustering_frame_offset_s))])
        for t in member_t
    ]
    counts = pd.Series(terrain).value_counts().to_dict()
    print(
        f"\ncontext {args.context} at {args.at} s: {len(members)} members {counts}; own "
        f"k-th-neighbour distances (k = {params.gate_neighbours}) median {np.median(kth):.4f}, "
        f"90th percentile {np.quantile(kth, 0.9):.4f}, {params.gate_quantile:g} quantile "
        f"{np.quantile(kth, params.gate_quantile):.4f}, largest {kth.max():.4f}; gate {gate:.4f}"
    )
    order = np.argsort(kth)[::-1][:3]
    if len(member_t) == len(kth):
        for j in order:
            print(f"  member at {member_t[j]:.1f} s ({terrain[j]}): {kth[j]:.4f}")
    result = {
        "frames": len(frames),
        "ids_differing_from_log": mismatches,
        "context": args.context,
        "members": int(len(members)),
        "member_terrains": counts,
        "kth_median": float(np.median(kth)),
        "kth_q90": float(np.quantile(kth, 0.9)),
        "kth_gate_quantile": float(np.quantile(kth, params.gate_quantile)),
        "gate": gate,
    }
    if args.terrain:
        nxt = log[(log["terrain"] == args.terrain) & (log["t"] > args.at)].head(12)
        z = nxt[features].to_numpy(float)
        d = np.sqrt(((z[:, None, :] - members[None]) ** 2).sum(-1))
        kd = np.sort(d, axis=1)[:, params.gate_neighbours - 1]
        print(f"next {args.terrain} frames' k-th-neighbour distance to them: {np.round(kd, 3)}")
        result["terrain_kth"] = [float(x) for x in kd]
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
