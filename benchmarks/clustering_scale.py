"""Re-clustering cost of the bounded context clusterer vs full HDBSCAN, N = 1k .. 100k frames.

One pass over a synthetic drive (four terrains, a fifth appearing late, transitions, outliers,
slow light drift; 36 numbers per frame at 10 Hz). Every frame goes through
``ContextClusterer.assign`` (timed); the store is re-clustered every 10 s of driving up to
``--dense-until`` frames and every 100 s after that (to keep the benchmark short; the store's
size does not depend on it). At each checkpoint N the benchmark times a re-clustering of the
store (median of repeats, on copies; wall-clock and CPU time, the latter close to what an
unloaded core takes, BLAS being single-threaded there), its memory (bytes held by the store,
peak allocation during the re-clustering, by tracemalloc), and, where N <= --full-max, full
scikit-learn HDBSCAN on all N frames with the same parameters (time, peak allocation) and the
adjusted Rand index between the two labelings of all N frames (bounded: ``predict`` with the
re-clustered store; full: HDBSCAN labels). Timed claims are ratios against full HDBSCAN in the
same run.

With ``--course-laps K`` it also drives K laps of the default course at 8 m/s (camera at 10 Hz,
descriptor features of the rendered ground), clusters online with the default parameters
(re-clustering every 10 s) and reports the context metrics, and the final labels against the
true terrains and against full HDBSCAN (transition strips excluded from the truth scores).

Usage: python benchmarks/clustering_scale.py [--quick] [--course-laps K]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import statistics
import time
import tracemalloc

import numpy as np
from sklearn.metrics import adjusted_rand_score

from pcvfe_drake.contexts.clustering import ClusteringParams, ContextClusterer, full_hdbscan_labels
from pcvfe_drake.contexts.feature_streams import synthetic_feature_stream
from pcvfe_drake.contexts.metrics import adjusted_rand


def _peak_bytes(fn) -> tuple[object, int]:
    """Result of ``fn()`` and the peak of memory allocated while it ran [bytes]."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    result = fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return result, int(peak)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="N up to 10k, full up to 5k")
    parser.add_argument("--full-max", type=int, default=None, help="largest N for full HDBSCAN")
    parser.add_argument("--dense-until", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--course-laps", type=float, default=0.0, help="also cluster K laps of the default course"
    )
    args = parser.parse_args()

    checkpoints = (
        [1_000, 2_000, 5_000, 10_000]
        if args.quick
        else [1_000, 2_000, 5_000, 10_000, 20_000, 50_000, 100_000]
    )
    full_max = args.full_max if args.full_max is not None else (5_000 if args.quick else 20_000)
    params = ClusteringParams()
    rate = params.frame_rate_hz
    lap_s = 25.0 + 22.0 + 30.0 + 24.0 + 25.0
    n_laps = int(np.ceil(max(checkpoints) / (lap_s * rate))) + 1
    stream = synthetic_feature_stream(
        n_laps=n_laps, late_terrain_from_lap=3, drift=0.3, seed=args.seed
    )
    print(
        f"stream: {stream.z.shape[0]} frames x {stream.z.shape[1]} numbers, {n_laps} laps; "
        f"checkpoints {checkpoints}; full HDBSCAN up to {full_max}",
        flush=True,
    )

    clusterer = ContextClusterer(params)
    assign_s: list[float] = []
    assign_cpu_s: list[float] = []
    online_ids = np.empty(max(checkpoints), dtype=int)
    next_recluster = 10.0
    rows: list[dict] = []
    for i in range(max(checkpoints)):
        t = float(stream.t_s[i])
        a, a_cpu = time.perf_counter(), time.process_time()
        online_ids[i] = clusterer.assign(stream.z[i], t)
        assign_s.append(time.perf_counter() - a)
        assign_cpu_s.append(time.process_time() - a_cpu)
        if t >= next_recluster:
            clusterer.recluster(t)
            next_recluster += 10.0 if i < args.dense_until else 100.0
        n = i + 1
        if n not in checkpoints:
            continue
        z = stream.z[:n]
        times, cpu_times = [], []
        for _ in range(max(1, args.repeats)):
            probe = copy.deepcopy(clusterer)
            start, cpu_start = time.perf_counter(), time.process_time()
            probe.recluster(t)
            times.append(time.perf_counter() - start)
            cpu_times.append(time.process_time() - cpu_start)
        # Memory in a separate run: tracemalloc slows allocation-heavy code down.
        spare = copy.deepcopy(clusterer)
        _, peak = _peak_bytes(lambda c=spare, t=t: c.recluster(t))
        ours = probe.predict(z)
        row = {
            "n": n,
            "stored": probe.n_stored,
            "stored_bytes": probe.stored_bytes,
            "recluster_s": statistics.median(times),
            "recluster_cpu_s": statistics.median(cpu_times),
            "recluster_peak_bytes": peak,
            "n_contexts": len(probe.table().active_ids),
            "ari_bounded_vs_truth": adjusted_rand(stream.label[:n], ours),
            "noise_fraction_bounded": float(np.mean(ours < 0)),
        }
        if n <= full_max:
            start, cpu_start = time.perf_counter(), time.process_time()
            full = full_hdbscan_labels(z, params)
            full_s = time.perf_counter() - start
            full_cpu_s = time.process_time() - cpu_start
            _, full_peak = _peak_bytes(lambda z=z: full_hdbscan_labels(z, params))
            row.update(
                {
                    "full_s": full_s,
                    "full_cpu_s": full_cpu_s,
                    "full_peak_bytes": full_peak,
                    "full_data_bytes": int(z.nbytes),
                    "speedup_vs_full": full_s / row["recluster_s"],
                    "ari_bounded_vs_full": float(adjusted_rand_score(full, ours)),
                    "ari_full_vs_truth": adjusted_rand(stream.label[:n], full),
                    "noise_fraction_full": float(np.mean(full < 0)),
                    "n_clusters_full": int(full.max() + 1),
                }
            )
        rows.append(row)
        print(
            "  ".join(
                f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()
            ),
            flush=True,
        )

    a_ms = np.array(assign_s) * 1e3
    with_full = [r for r in rows if "ari_bounded_vs_full" in r]
    result = {
        "benchmark": "clustering_scale",
        "quick": args.quick,
        "feature_dim": int(stream.z.shape[1]),
        "params": {
            "min_cluster_size": params.min_cluster_size,
            "min_samples": params.min_samples,
            "max_stored": params.max_stored,
            "noise_capacity": params.noise_capacity,
        },
        "cpu_count": os.cpu_count(),
        "load_avg_1min": os.getloadavg()[0],
        "python": platform.python_version(),
        "rows": rows,
        "assign_ms_mean": float(a_ms.mean()),
        "assign_ms_median": float(np.median(a_ms)),
        "assign_ms_p99": float(np.percentile(a_ms, 99)),
        "assign_cpu_ms_mean": float(np.mean(assign_cpu_s) * 1e3),
        "recluster_s_max": max(r["recluster_s"] for r in rows),
        "recluster_s_at_max_n": rows[-1]["recluster_s"],
        "recluster_cpu_s_at_max_n": rows[-1]["recluster_cpu_s"],
        "ari_bounded_vs_full_min": min((r["ari_bounded_vs_full"] for r in with_full), default=None),
        "speedup_vs_full_at_largest_full_n": with_full[-1]["speedup_vs_full"]
        if with_full
        else None,
    }
    if args.course_laps > 0:
        result["default_course"] = _default_course(args.course_laps, params)
    print(json.dumps(result))
    return 0


def _default_course(laps: float, params: ClusteringParams) -> dict:
    """Online clustering of descriptor features along the default course (see module doc)."""
    from pcvfe_drake.contexts.metrics import context_metrics
    from pcvfe_drake.control.course import load_course
    from pcvfe_drake.diagrams.world_io import world_terrain_map
    from pcvfe_drake.perception.camera import DownwardCamera
    from pcvfe_drake.perception.features import make_extractor

    course = load_course(None)
    terrain_map = world_terrain_map("paper")
    camera = DownwardCamera(terrain_map)
    extractor = make_extractor("descriptor")
    speed, rate = 8.0, params.frame_rate_hz
    n = int(laps * course.length / speed * rate)
    t = np.arange(n) / rate
    x, y, heading, _ = course.sample(course.wrap_s(speed * t))
    print(
        f"default course: rendering {n} frames ({laps} laps of {course.length:.0f} m)", flush=True
    )
    z = np.asarray(
        extractor.extract([camera.render(x[i], y[i], heading[i], speed) for i in range(n)])
    )
    names = np.asarray(terrain_map.name_at(np.column_stack([x, y])), dtype=object)
    clusterer = ContextClusterer(params)
    ids = np.empty(n, dtype=int)
    next_recluster = 10.0
    for i in range(n):
        ids[i] = clusterer.assign(z[i], float(t[i]))
        if t[i] >= next_recluster - 1e-9:
            clusterer.recluster(float(t[i]))
            next_recluster += 10.0
    counts = {str(k): int(v) for k, v in zip(*np.unique(names, return_counts=True), strict=True)}
    # Transition strips are the terrains covering little of the drive.
    strips = tuple(k for k, v in counts.items() if v < 0.05 * n)
    excluded = strips + ("",)
    m = context_metrics(t, names, ids, excluded_labels=excluded)
    final = clusterer.predict(z)
    full = full_hdbscan_labels(z, params)
    out = {
        "frames": n,
        "feature_dim": int(z.shape[1]),
        "frames_per_terrain": counts,
        "excluded_strips": list(strips),
        "online": {k: v for k, v in m.to_dict().items() if k != "reid_latencies_s"},
        "final_ari_vs_truth": adjusted_rand(names, final, excluded_labels=excluded),
        "full_ari_vs_truth": adjusted_rand(names, full, excluded_labels=excluded),
        "final_ari_vs_full": float(adjusted_rand_score(full, final)),
        # The same without the strip frames (full HDBSCAN puts most of them into a neighbouring
        # terrain's cluster, the outlier gate calls them noise).
        "final_ari_vs_full_without_strips": float(
            adjusted_rand_score(full[~np.isin(names, strips)], final[~np.isin(names, strips)])
        ),
        "strip_frames_noise_final": float(np.mean(final[np.isin(names, strips)] < 0)),
        "strip_frames_noise_full": float(np.mean(full[np.isin(names, strips)] < 0)),
        "final_contexts": len(clusterer.table().active_ids),
        "full_clusters": int(full.max() + 1),
    }
    print(json.dumps(out), flush=True)
    return out


if __name__ == "__main__":
    raise SystemExit(main())
