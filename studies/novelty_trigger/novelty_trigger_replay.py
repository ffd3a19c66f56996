"""The novelty-triggered re-clustering against the paper's period alone, on logged features.

Replays the feature vectors logged in finished runs (``drive_log``'s ``f_*`` columns, one per
camera frame) through :class:`ContextClusterer` twice: with the 0.1 Hz re-clustering only, and
with the trigger (``--window`` seconds, ``ClusteringParams.novelty_window_s``) as the
ContextClustering system runs it. Per run and setting: the time from entering each terrain
until the visit's context is first reported (``drive_metrics.transition_response``'s
``context_id_s``), frames on a terrain reported as a context whose majority terrain is another
(wrong) and frames of the transition strips reported as any context, the triggered attempts and
the kept ones, and the wall time of every HDBSCAN re-clustering (mean, max) on the stored set.
A third setting is the clustering a scenario ships (``--scenario``, default
``paper_eval_effects``), a fourth with ``--hold S`` that clustering with
``continuation_hold_s`` S (docs/clustering.md, "Continuing a visit"). Two measures of what
the controller would be handed, with the estimator's 1 s noise hold
(``LiveFitConfig.noise_hold_s``): ``unknown_on_known_s``, seconds on a terrain after its context
was first reported with no context handed (the unknown-context value), and
``handed_higher_s``, seconds handed a context whose terrain's friction is more than 0.05 above
the friction under the car (transition strips, the hold onto a new terrain).

Usage: python studies/novelty_trigger/novelty_trigger_replay.py
       [RUN_DIR ...] [--window 6] [--scenario NAME]
[--hold S] [--quick]
Without run folders it makes one (``make_run`` below: ``pcvfe simulate
paper_eval_effects --seed 0``, one lap; ``--quick``: its first 45 s).
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.contexts.clustering import NOISE, ClusteringParams, ContextClusterer
from pcvfe_drake.runs import drive_metrics

STRIPS = ("gravel", "dry_soil")
PERIOD_S = 10.0
NOISE_HOLD_S = 1.0
HIGHER_TOL = 0.05


def make_run(out: Path, scenario: str, duration_s: float | None = None) -> Path:
    """One ``pcvfe simulate`` of ``scenario``, seed 0, no Meshcat, into ``out`` (``duration_s``:
    only its first seconds; None: the scenario's length)."""
    from pcvfe_drake.cli import main as pcvfe

    cmd = ["simulate", scenario, "--seed", "0", "--no-meshcat", "--out", str(out)]
    cmd += ["--duration", f"{duration_s:g}"] if duration_s is not None else []
    print("making a run: pcvfe " + " ".join(cmd), flush=True)
    if pcvfe(cmd) != 0:
        raise SystemExit("pcvfe simulate failed")
    return out


def read_log(folder: Path) -> pd.DataFrame:
    parquet = folder / "drive_log.parquet"
    return pd.read_parquet(parquet) if parquet.is_file() else pd.read_csv(folder / "drive_log.csv")


def replay(log: pd.DataFrame, params: ClusteringParams) -> dict:
    """Frame by frame (rows at multiples of the camera period); ids per log row."""
    cols = [c for c in log.columns if c.startswith("f_")]
    if not cols:
        raise ValueError("the drive log has no feature columns f_*: log the features to replay")
    t = log["t"].to_numpy(float)
    ticks = np.round(t * params.frame_rate_hz, 6)
    frames = np.flatnonzero(np.isclose(ticks, np.round(ticks)))
    features = log[cols].to_numpy(float)
    clusterer = ContextClusterer(params)
    ids = np.full(len(log), NOISE)
    durations = []
    next_period = PERIOD_S
    for k, i in enumerate(frames):
        if t[i] >= next_period - 1e-9:
            cid = clusterer.assign(features[i], t[i])
            start = time.perf_counter()
            clusterer.recluster(t[i])
            durations.append(time.perf_counter() - start)
            next_period += PERIOD_S
        else:
            # a triggered attempt's time includes the frame's assignment (well under 1 ms)
            tries = clusterer.novelty_counts[0]
            start = time.perf_counter()
            cid, _ = clusterer.assign_frame(features[i], t[i])
            if clusterer.novelty_counts[0] > tries:
                durations.append(time.perf_counter() - start)
        end = frames[k + 1] if k + 1 < frames.size else len(log)
        ids[i + 1 : end + 1] = cid  # the logged id follows its frame by one row
    tries, kept = clusterer.novelty_counts
    return {"ids": ids, "tries": tries, "kept": kept, "durations_s": durations}


def score(log: pd.DataFrame, ids: np.ndarray) -> dict:
    terrain = log["terrain"].astype(str).to_numpy()
    on_terrain = ~np.isin(terrain, STRIPS)
    majority = {}
    for k in np.unique(ids[ids >= 0]):
        names = list(terrain[(ids == k) & on_terrain])
        majority[int(k)] = max(set(names), key=names.count) if names else None
    wrong = sum(
        1 for i in np.flatnonzero((ids >= 0) & on_terrain) if majority[int(ids[i])] != terrain[i]
    )
    frame_rows = max(1, round(0.1 / float(np.median(np.diff(log["t"].to_numpy(float))))))
    relog = log.copy()
    relog["context"] = ids
    entries = drive_metrics.transition_response(relog, STRIPS)["entries"]
    return {
        "context_id_s": {e["terrain"]: e["context_id_s"] for e in entries},
        "wrong_frames": round(wrong / frame_rows, 1),
        "strip_frames": round(int(np.sum((ids >= 0) & ~on_terrain)) / frame_rows, 1),
        **handed_times(log, ids),
    }


def handed_times(log: pd.DataFrame, ids: np.ndarray) -> dict:
    """``unknown_on_known_s`` and ``handed_higher_s`` (module docstring) of per-row ids."""
    t = log["t"].to_numpy(float)
    mu = log["mu_true"].to_numpy(float)
    terrain = log["terrain"].astype(str).to_numpy()
    handed = np.full(ids.size, NOISE)
    last, t_last = NOISE, -np.inf
    for i, k in enumerate(ids):
        if k >= 0:
            last, t_last = k, t[i]
        if t[i] - t_last <= NOISE_HOLD_S + 1e-9:
            handed[i] = last
    dt = np.gradient(t)
    home, home_mu = {}, {}
    for k in np.unique(ids[ids >= 0]):
        names, counts = np.unique(terrain[ids == k], return_counts=True)
        home[int(k)] = names[counts.argmax()]
        home_mu[int(k)] = float(np.median(mu[(ids == k) & (terrain == home[int(k)])]))
    handed_mu = np.array([home_mu[int(k)] if k >= 0 else -np.inf for k in handed])
    unknown = 0.0
    for k, name in home.items():
        after = np.arange(ids.size) > np.flatnonzero(ids == k)[0]
        unknown += float(dt[(terrain == name) & (handed < 0) & after].sum())
    return {
        "unknown_on_known_s": round(unknown, 2),
        "handed_higher_s": round(float(dt[handed_mu > mu + HIGHER_TOL].sum()), 2),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", type=Path, help="run folders with a drive log")
    ap.add_argument("--window", type=float, default=6.0, help="novelty_window_s [s]")
    ap.add_argument("--scenario", default="paper_eval", help="the third setting: its clustering")
    ap.add_argument(
        "--hold",
        type=float,
        default=None,
        help="a fourth setting: the scenario's clustering with continuation_hold_s HOLD [s] "
        "(0: a frame beyond the widened gate ends the visit, as without a hold)",
    )
    ap.add_argument("--quick", action="store_true", help="without runs: a 45 s run")
    args = ap.parse_args(argv)
    if not args.runs:
        with tempfile.TemporaryDirectory(prefix="novelty_replay_") as tmp:
            made = make_run(Path(tmp) / "run", "paper_eval", 45.0 if args.quick else None)
            return main([str(made), "--window", str(args.window), "--scenario", args.scenario])
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    settings = {
        "period": ClusteringParams(),
        "trigger": ClusteringParams(novelty_window_s=args.window),
        "scenario": load_scenario(args.scenario).clustering_params(),
    }
    if args.hold is not None:
        settings["hold"] = replace(settings["scenario"], continuation_hold_s=args.hold)
    out = {name: [] for name in settings}
    durations = {name: [] for name in settings}
    for folder in args.runs:
        log = read_log(folder)
        for name, params in settings.items():
            r = replay(log, params)
            row = {"run": folder.name, **score(log, r["ids"]), "tries": r["tries"]}
            row["kept"] = r["kept"]
            out[name].append(row)
            durations[name] += r["durations_s"]
            lat = {k: None if v is None else round(v, 2) for k, v in row["context_id_s"].items()}
            print(
                f"{folder.name} {name:8s} id after entry {lat} wrong {row['wrong_frames']} "
                f"strip {row['strip_frames']} triggered {r['kept']}/{r['tries']} unknown on "
                f"known {row['unknown_on_known_s']} s, higher {row['handed_higher_s']} s"
            )
    summary = {}
    for name, rows in out.items():
        per = {}
        for terrain in sorted({k for r in rows for k in r["context_id_s"]}):
            vals = [r["context_id_s"].get(terrain) for r in rows]
            got = [v for v in vals if v is not None]
            per[terrain] = {
                "mean_s": round(float(np.mean(got)), 2) if got else None,
                "max_s": round(float(np.max(got)), 2) if got else None,
                "never": sum(v is None for v in vals),
            }
        d = np.array(durations[name]) * 1e3
        summary[name] = {
            "context_id_after_entry": per,
            "wrong_frames": [r["wrong_frames"] for r in rows],
            "strip_frames": [r["strip_frames"] for r in rows],
            "unknown_on_known_s": [r["unknown_on_known_s"] for r in rows],
            "handed_higher_s": [r["handed_higher_s"] for r in rows],
            "kept_per_run": [r["kept"] for r in rows],
            "tries_per_run": [r["tries"] for r in rows],
            "hdbscan_ms_mean": round(float(d.mean()), 1) if d.size else None,
            "hdbscan_ms_max": round(float(d.max()), 1) if d.size else None,
        }
        print(
            f"{name}: id after entry {per}; HDBSCAN {summary[name]['hdbscan_ms_mean']} ms "
            f"per call (max {summary[name]['hdbscan_ms_max']})"
        )
    head = {"benchmark": "novelty_trigger_replay", "window_s": args.window}
    print(json.dumps({**head, "scenario": args.scenario, **summary}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
