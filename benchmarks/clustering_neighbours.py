"""The clustering's neighbour searches: the project's brute force against scikit-learn's.

The context clusterer (``pcvfe_drake.contexts``) searches neighbours in three places, all on
its bounded store (at most ``max_stored`` = 2000 vectors of 36 numbers by default):

- ``kth``: each context member's leave-one-out distance to its k-th nearest other member (the
  outlier gate, at every re-clustering; ``density_gate.kth_member_distances``);
- ``detach``: within each HDBSCAN cluster, the graph of members closer than the cluster's gate
  and its connected components, then the pockets on the tree of the survivors (every
  re-clustering; ``density_gate.detach_small_groups``; the pocket step is the project's own in
  both columns);
- ``gate``: a frame's nearest stored member and its k-th nearest member of that context, the
  online assignment of every camera frame (``GateIndex.labels``), one frame at a time and in
  blocks of 4096 (``ContextClusterer.predict``).

The store is that of a ``ContextClusterer`` after a synthetic drive (the stream of
``benchmarks/clustering_scale.py``, re-clustered every 10 s). Each search is timed with the
project's code and with scikit-learn's ``NearestNeighbors`` (``kneighbors``,
``radius_neighbors_graph``) for each of its algorithms (brute, kd_tree, ball_tree), under the
one-BLAS-thread limit the clusterer runs with, best of ``--repeats``; the results of both are
checked to agree. The clusterer keeps whichever is faster: the decision and its figures are in
``docs/clustering.md``.

Usage: ``python benchmarks/clustering_neighbours.py [--quick]``; the last stdout line is a JSON
object.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from scipy.sparse.csgraph import connected_components
from sklearn.metrics import pairwise_distances
from sklearn.neighbors import NearestNeighbors
from threadpoolctl import threadpool_limits

from pcvfe_drake.contexts.clustering import ClusteringParams, ContextClusterer, hdbscan_labels
from pcvfe_drake.contexts.clustering_params import NOISE
from pcvfe_drake.contexts.density_gate import (
    GateIndex,
    detach_pockets,
    detach_small_groups,
    gate_radius,
    kth_member_distances,
)
from pcvfe_drake.contexts.feature_streams import synthetic_feature_stream

ALGORITHMS = ("brute", "kd_tree", "ball_tree")


def sk_kth(members: np.ndarray, k: int, algorithm: str) -> np.ndarray:
    """``kth_member_distances`` with scikit-learn (a fitted set queried without its own points
    gives leave-one-out neighbours)."""
    m = members.shape[0]
    k = min(k, m - 1)
    if k < 1:
        return np.zeros(m)
    dist, _ = NearestNeighbors(n_neighbors=k, algorithm=algorithm).fit(members).kneighbors()
    return dist[:, k - 1]


def sk_detach(x, labels, weights, params: ClusteringParams, algorithm: str) -> np.ndarray:
    """``detach_small_groups`` with scikit-learn's k-th neighbours and radius graph."""
    out = labels.copy()
    for k in np.unique(labels[labels >= 0]):
        idx = np.flatnonzero(labels == k)
        members = x[idx]
        kk = min(params.gate_neighbours, idx.size - 1)
        if kk < 1:
            continue
        nn = NearestNeighbors(n_neighbors=kk, algorithm=algorithm).fit(members)
        kth = nn.kneighbors()[0][:, kk - 1]
        gate = gate_radius(kth, params, float((members * members).sum(1).max()))
        graph = nn.radius_neighbors_graph(radius=gate, mode="connectivity")
        n_comp, comp = connected_components(graph, directed=False)
        keep = np.ones(idx.size, dtype=bool)
        if n_comp > 1:
            mass = np.bincount(comp, weights=weights[idx], minlength=n_comp)
            keep = mass[comp] >= params.min_cluster_size
        alive = np.flatnonzero(keep)
        full = pairwise_distances(members[alive], metric="sqeuclidean")
        np.fill_diagonal(full, np.inf)
        keep[alive[detach_pockets(full, weights[idx[alive]], params)]] = False
        out[idx[~keep]] = NOISE
    return out


class SkGateIndex:
    """``GateIndex.labels`` with scikit-learn: one index over all members for the nearest
    member, one per context for the k-th nearest member of that context."""

    def __init__(self, index: GateIndex, algorithm: str) -> None:
        self.index = index
        self.all = NearestNeighbors(n_neighbors=1, algorithm=algorithm).fit(index.x)
        self.per_context = {
            cid: NearestNeighbors(n_neighbors=min(index.k, e - s), algorithm=algorithm).fit(
                index.x[s:e]
            )
            for cid, (s, e) in index.bounds.items()
        }

    def labels(self, z: np.ndarray) -> np.ndarray:
        out = np.full(z.shape[0], NOISE, dtype=int)
        cand = self.index.ids[self.all.kneighbors(z, return_distance=False)[:, 0]]
        for cid in np.unique(cand):
            rows = np.flatnonzero(cand == cid)
            kth = self.per_context[int(cid)].kneighbors(z[rows])[0][:, -1]
            out[rows] = np.where(kth**2 <= self.index.gate_sq[int(cid)], cid, NOISE)
        return out


def best_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times) * 1e3


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="3000 frames instead of 6000")
    parser.add_argument("--frames", type=int, default=None, help="frames driven before timing")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    n_frames = args.frames or (3000 if args.quick else 6000)

    params = ClusteringParams()
    lap_frames = (25.0 + 22.0 + 30.0 + 24.0) * params.frame_rate_hz  # the stream's four terrains
    n_laps = int(np.ceil((n_frames + 4096) / lap_frames)) + 1
    stream = synthetic_feature_stream(n_laps=n_laps, late_terrain_from_lap=3, drift=0.3, seed=0)
    clusterer = ContextClusterer(params)
    next_recluster = 10.0
    for i in range(n_frames):
        t = float(stream.t_s[i])
        clusterer.assign(stream.z[i], t)
        if t >= next_recluster:
            clusterer.recluster(t)
            next_recluster += 10.0
    index = clusterer._index
    used = clusterer._used
    x, w = clusterer._x[used], clusterer._w[used]
    frames = stream.z[n_frames : n_frames + 4096]
    one = frames[:1]
    sizes = [e - s for s, e in index.bounds.values()]
    print(
        f"store: {x.shape[0]} vectors x {x.shape[1]}; {len(sizes)} contexts of {sizes} members",
        flush=True,
    )

    rows: dict[str, dict[str, float]] = {}
    agree = True
    with threadpool_limits(limits=1, user_api="blas"):
        raw = hdbscan_labels(x, params.min_cluster_size, params.min_samples)
        k = params.gate_neighbours
        members = [index.x[s:e] for s, e in index.bounds.values()]
        ours_kth = [kth_member_distances(m, k) for m in members]
        ours_detach = detach_small_groups(x, raw, w, params)
        ours_gate = index.labels(frames)
        rows["project"] = {
            "kth_ms": best_ms(lambda: [kth_member_distances(m, k) for m in members], args.repeats),
            "detach_ms": best_ms(lambda: detach_small_groups(x, raw, w, params), args.repeats),
            "gate_one_frame_ms": best_ms(lambda: index.labels(one), 10 * args.repeats),
            "gate_4096_frames_ms": best_ms(lambda: index.labels(frames), args.repeats),
        }
        for alg in ALGORITHMS:
            sk_index = SkGateIndex(index, alg)
            kth_ok = all(
                np.allclose(sk_kth(m, k, alg), ref, rtol=1e-9, atol=1e-12)
                for m, ref in zip(members, ours_kth, strict=True)
            )
            detach_ok = np.array_equal(sk_detach(x, raw, w, params, alg), ours_detach)
            gate_ok = np.array_equal(sk_index.labels(frames), ours_gate)
            same = kth_ok and detach_ok and gate_ok
            agree &= same
            rows[f"sklearn_{alg}"] = {
                "kth_ms": best_ms(lambda a=alg: [sk_kth(m, k, a) for m in members], args.repeats),
                "detach_ms": best_ms(lambda a=alg: sk_detach(x, raw, w, params, a), args.repeats),
                "gate_one_frame_ms": best_ms(lambda s=sk_index: s.labels(one), 10 * args.repeats),
                "gate_4096_frames_ms": best_ms(lambda s=sk_index: s.labels(frames), args.repeats),
            }
            print(f"sklearn {alg}: results agree with the project's: {same}", flush=True)
    keys = ("kth_ms", "detach_ms", "gate_one_frame_ms", "gate_4096_frames_ms")
    print(f"{'':>18}" + "".join(f"{key:>22}" for key in keys))
    for name, row in rows.items():
        print(f"{name:>18}" + "".join(f"{row[key]:>22.3f}" for key in keys))
    base = rows["project"]
    result = {
        "stored": int(x.shape[0]),
        "dim": int(x.shape[1]),
        "context_sizes": [int(s) for s in sizes],
        "results_agree": bool(agree),
        **{f"{name}_{key}": value for name, row in rows.items() for key, value in row.items()},
        **{
            f"best_sklearn_over_project_{key.removesuffix('_ms')}_ratio": min(
                rows[f"sklearn_{alg}"][key] for alg in ALGORITHMS
            )
            / base[key]
            for key in keys
        },
        "load_average_1min": os.getloadavg()[0],
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
