"""Peers of the bounded context clusterer: the ``hdbscan`` and ``fast-hdbscan`` packages.

Same feature stream as ``benchmarks/clustering_scale.py`` (``synthetic_feature_stream``: four
terrains, a fifth from lap 3, transitions, outliers, light drift; 36 numbers per frame at 10 Hz).
The bounded ``ContextClusterer`` is driven through the stream as in that benchmark (assignment
every frame, re-clustering every 10 s of driving). At each checkpoint N it times:

* ours: one re-clustering of the bounded store (median of ``--repeats`` on copies), labels of all
  N frames by ``predict``;
* full HDBSCAN over all N frames (what the paper re-runs every 10 s) with the same
  ``min_cluster_size`` / ``min_samples`` by three implementations: scikit-learn's ``HDBSCAN``
  (the project's reference, ``full_hdbscan_labels``), ``hdbscan.HDBSCAN`` (the
  scikit-learn-contrib package; its documented default ``algorithm="best"``, which picks a
  Boruvka KD-tree for data of this dimension, ``core_dist_n_jobs=-1``: all cores) and
  ``fast_hdbscan.HDBSCAN`` (numba, parallel; its first call compiles and is timed separately as
  ``fast_hdbscan_compile_s``).

For each: wall time and CPU time, ARI against the planted truth and ARI of our labels against
its labels. A peer whose previous checkpoint took longer than ``--peer-cap-s`` is not run at the
larger ones (reported as ``skipped``). A peer that is not installed is reported as missing
(``pip install .[peers]`` or ``make bench`` installs them), not as a failure.

Usage: python benchmarks/peers_clustering.py [--quick]. Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import copy
import importlib
import importlib.metadata
import json
import os
import platform
import statistics
import time
import warnings

import numpy as np
from sklearn.metrics import adjusted_rand_score

from pcvfe_drake.contexts.clustering import ClusteringParams, ContextClusterer, full_hdbscan_labels
from pcvfe_drake.contexts.feature_streams import synthetic_feature_stream
from pcvfe_drake.contexts.metrics import adjusted_rand

PEERS = {"hdbscan": "hdbscan", "fast_hdbscan": "fast-hdbscan"}


def _load(module: str):
    try:
        return importlib.import_module(module), None
    except Exception as exc:  # ImportError, or a broken binary build
        return None, f"{type(exc).__name__}: {exc}"


def _runner(name: str, mod, params: ClusteringParams):
    mcs, ms = params.min_cluster_size, params.min_samples
    if name == "sklearn":
        return lambda z: full_hdbscan_labels(z, params)
    if name == "hdbscan":

        def run(z):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = mod.HDBSCAN(
                    min_cluster_size=mcs, min_samples=ms, algorithm="best", core_dist_n_jobs=-1
                )
                return model.fit_predict(z)

        return run
    if name == "fast_hdbscan":

        def run(z):
            return mod.HDBSCAN(min_cluster_size=mcs, min_samples=ms).fit_predict(z)

        return run
    raise ValueError(name)


def _timed(fn, *args):
    w, c = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, time.perf_counter() - w, time.process_time() - c


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="N up to 5k")
    parser.add_argument("--max-n", type=int, default=None, help="largest checkpoint")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--peer-cap-s", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    checkpoints = [1_000, 2_000, 5_000] if args.quick else [1_000, 2_000, 5_000, 10_000, 20_000]
    if args.max_n:
        checkpoints = [n for n in [1_000, 2_000, 5_000, 10_000, 20_000, 50_000] if n <= args.max_n]
    params = ClusteringParams()
    lap_s = 25.0 + 22.0 + 30.0 + 24.0 + 25.0
    n_laps = int(np.ceil(max(checkpoints) / (lap_s * params.frame_rate_hz))) + 1
    stream = synthetic_feature_stream(
        n_laps=n_laps, late_terrain_from_lap=3, drift=0.3, seed=args.seed
    )
    peers: dict[str, object] = {}
    missing: dict[str, str] = {}
    for module, dist in PEERS.items():
        mod, err = _load(module)
        if mod is None:
            missing[module] = f"{dist} not installed ({err}); `pip install .[peers]` installs it"
            print(f"PEER MISSING: {missing[module]}", flush=True)
        else:
            peers[module] = mod
    versions = {m: importlib.metadata.version(PEERS[m]) for m in peers}
    runners = {"sklearn": _runner("sklearn", None, params)}
    runners.update({m: _runner(m, peers[m], params) for m in peers})
    compile_s = None
    if "fast_hdbscan" in runners:  # numba compiles on the first call: not part of a re-clustering
        _, compile_s, _ = _timed(runners["fast_hdbscan"], stream.z[:500])
        print(f"fast_hdbscan first call (numba compile) {compile_s:.1f} s", flush=True)
    print(
        f"stream {stream.z.shape}; checkpoints {checkpoints}; peers {sorted(peers)}; "
        f"cpu_count {os.cpu_count()}, load {os.getloadavg()[0]:.1f}",
        flush=True,
    )

    clusterer = ContextClusterer(params)
    next_recluster = 10.0
    last_time = dict.fromkeys(runners, 0.0)
    rows = []
    for i in range(max(checkpoints)):
        t = float(stream.t_s[i])
        clusterer.assign(stream.z[i], t)
        if t >= next_recluster:
            clusterer.recluster(t)
            next_recluster += 10.0
        n = i + 1
        if n not in checkpoints:
            continue
        z, truth = stream.z[:n], stream.label[:n]
        times, cpus = [], []
        for _ in range(max(1, args.repeats)):
            probe = copy.deepcopy(clusterer)
            _, w, c = _timed(probe.recluster, t)
            times.append(w)
            cpus.append(c)
        ours = probe.predict(z)
        row = {
            "n": n,
            "ours_recluster_s": statistics.median(times),
            "ours_recluster_cpu_s": statistics.median(cpus),
            "ours_ari_vs_truth": adjusted_rand(truth, ours),
        }
        for name, fn in runners.items():
            if last_time[name] > args.peer_cap_s:
                row[f"{name}_skipped"] = f"previous N took {last_time[name]:.0f} s"
                continue
            labels, w, c = _timed(fn, z)
            labels = np.asarray(labels)
            last_time[name] = w
            row.update(
                {
                    f"{name}_s": w,
                    f"{name}_cpu_s": c,
                    f"{name}_ari_vs_truth": adjusted_rand(truth, labels),
                    f"ours_ari_vs_{name}": float(adjusted_rand_score(labels, ours)),
                    f"{name}_clusters": int(labels.max() + 1),
                    f"{name}_noise_fraction": float(np.mean(labels < 0)),
                    f"ratio_{name}_over_ours": w / row["ours_recluster_s"],
                }
            )
        rows.append(row)
        print(
            "  ".join(
                f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()
            ),
            flush=True,
        )

    def at_largest(key):
        vals = [r[key] for r in rows if key in r]
        return vals[-1] if vals else None

    result = {
        "benchmark": "peers_clustering",
        "quick": args.quick,
        "peers_missing": missing,
        "peer_versions": versions,
        "settings": {
            "min_cluster_size": params.min_cluster_size,
            "min_samples": params.min_samples,
            "hdbscan": "algorithm='best' (Boruvka KD-tree here), core_dist_n_jobs=-1",
            "fast_hdbscan": "defaults (numba parallel over all cores)",
        },
        "fast_hdbscan_compile_s": compile_s,
        "cpu_count": os.cpu_count(),
        "load_avg_1min": os.getloadavg()[0],
        "python": platform.python_version(),
        "rows": rows,
        "ratio_hdbscan_over_ours_at_largest_n": at_largest("ratio_hdbscan_over_ours"),
        "ratio_fast_hdbscan_over_ours_at_largest_n": at_largest("ratio_fast_hdbscan_over_ours"),
        "ratio_sklearn_over_ours_at_largest_n": at_largest("ratio_sklearn_over_ours"),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
