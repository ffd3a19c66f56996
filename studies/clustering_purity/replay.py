"""Replay the context clustering over stored drive logs and score what it would hand on.

The clustering sees only the camera's feature vectors, so a stored run's ``drive_log`` (its
``f_*`` columns, one camera frame per camera period) replays it offline, open-loop (the car's
path is the logged one): :class:`ContextClusterer` with the run's own clustering settings (its
``scenario.yaml``), called as ``systems/context_clustering.py`` calls it (``assign_frame`` per
frame at its offset after the camera tick, ``recluster`` every ``recluster_period_s``, taken
before a frame of the same instant only when the frame offset is positive). The replay is
trusted for a run only when its ids equal the logged ``context`` column on every frame
(``agreement`` 1.0, with the code that ran it); a changed clustering is then judged on the same
frames.

Per run (frame by frame, at the camera rate):

- ``carried_s``: frames given a context whose majority terrain so far (:func:`replay`) has a
  true friction more than ``CARRIED_TOL`` (0.05) above the friction under the car: the
  clustering hands on more grip than there is. ``carried_terrain_s``: of those, the frames on
  a terrain (not a transition strip). ``longest_carried_s``: the longest unbroken run of
  carried frames.
- ``carried_continued_s``: of the carried frames, those whose id came from the continuation
  (the widened gate), not from the context's own gate. ``unexplained_frames``: frames that would
  have continued or held a visit but that the car's speed did not let blur explain
  (``ContextClusterer.last_evidence``).
- ``purity``: over terrain frames given a context, the share whose terrain is their context's
  majority terrain (over the whole run).
- ``noise_fraction``: terrain frames given no context (-1). ``known_noise_fraction``: the same
  over the frames on a terrain after it was first given its own context (a known terrain
  missed, rather than a new one not yet named).
- per terrain visit: the time from its entry to the first frame given its own context (a context
  whose majority terrain over the run is the visit's): ``name_s`` over first visits (the latency
  of naming a new terrain), ``reid_s`` over revisits; visits that never get one are counted.
- ``n_contexts``, ``n_terrains``: contexts reported, terrains (not strips) visited.

Transition strips are the world file's terrains painted only by strips.

Usage (from the repository root, with the project's venv)::

    python studies/clustering_purity/replay.py RUN_OR_FOLDER... --out result.json
    python studies/clustering_purity/replay.py --compare before.json after.json
    python studies/clustering_purity/replay.py --held-out --compare before.json after.json
    python studies/clustering_purity/replay.py --held-out --compare b.json a.json --known x.json

A folder is searched for run folders (those holding ``drive_log.parquet`` or ``drive_log.csv``).
``--compare`` prints the two results side by side for the ``--dev`` folders (with
``--held-out`` also for the rest, the runs judged only at the end; with ``--known``, the rest
named in those earlier result files is held out and the others are fresh). The study:
``README.md`` here.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from pcvfe_drake.contexts import clustering as clustering_module
from pcvfe_drake.contexts.clustering import NOISE, ClusteringParams, ContextClusterer
from pcvfe_drake.worlds.world_file import resolve_world_path

CARRIED_TOL = 0.05
"""A context's terrain is carried onto a frame when its friction is more than this above the
frame's (the project's tolerance on a friction estimate)."""
DEV_DEFAULT = ("/work/runs/checkmu", "/work/runs/climb")
"""Run folders looked at while developing the clustering change; the others are held out."""


@dataclass
class RunFrames:
    """One run's camera frames and the settings its clustering ran with."""

    folder: Path
    t_s: np.ndarray
    """(N,) time each frame was assigned [s] (camera tick plus the clustering's offset)."""
    z: np.ndarray
    """(N, d) feature vectors."""
    terrain: np.ndarray
    """(N,) terrain under the car at the frame (str)."""
    mu: np.ndarray
    """(N,) true friction under the car."""
    speed_mps: np.ndarray | None
    """(N,) the car's (measured) speed when the frame was taken, as the clustering system reads
    it from the state; None: the replay passes no speed (the clustering before it took one)."""
    logged: np.ndarray
    """(N,) context id the run logged for the frame."""
    params: ClusteringParams
    period_s: float
    """Re-clustering period [s]."""
    strips: tuple[str, ...]
    camera_period_s: float
    estimator: str


def run_folders(paths: list[Path]) -> list[Path]:
    """Run folders (holding a drive log) among ``paths`` and below them, sorted."""
    out = set()
    for p in paths:
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such file or folder")
        for name in ("drive_log.parquet", "drive_log.csv"):
            if (p / name).is_file():
                out.add(p)
            out |= {q.parent for q in p.rglob(name)}
    return sorted(out)


def _read_log(folder: Path) -> pd.DataFrame:
    parquet = folder / "drive_log.parquet"
    if parquet.is_file():
        return pd.read_parquet(parquet)
    return pd.read_csv(folder / "drive_log.csv")


def _strips(world: str | None, folder: Path) -> tuple[str, ...]:
    """Terrains of the run's world painted only by strips (() when the world is not found)."""
    if not world:
        return ()
    try:
        spec = yaml.safe_load(resolve_world_path(world, folder).read_text()) or {}
    except (FileNotFoundError, yaml.YAMLError):
        return ()
    painted = {r.get("terrain") for r in spec.get("regions") or []}
    painted |= set(((spec.get("label_image") or {}).get("legend") or {}).values())
    strips = [s.get("terrain") for s in spec.get("strips") or []]
    return tuple(dict.fromkeys(n for n in strips if n not in painted))


def load_run(folder: Path) -> RunFrames:
    """The camera frames of a run folder; ValueError naming the file when it cannot be replayed."""
    scenario_file = folder / "scenario.yaml"
    if not scenario_file.is_file():
        raise ValueError(f"{scenario_file}: missing (the run's clustering settings)")
    scenario = yaml.safe_load(scenario_file.read_text()) or {}
    rates = scenario.get("rates") or {}
    camera_period_s = float(rates.get("camera_period_s", 0.1))
    known = {f.name for f in fields(ClusteringParams)}
    given = scenario.get("clustering") or {}
    unknown = sorted(set(given) - known)
    if unknown:
        raise ValueError(f"{scenario_file}: clustering fields this code lacks: {unknown}")
    params = replace(
        ClusteringParams(**given),
        frame_rate_hz=1.0 / camera_period_s,
        seed=int(scenario.get("seed", 0)),
    )
    log = _read_log(folder)
    cols = [c for c in log.columns if c.startswith("f_")]
    missing = [c for c in ("t", "terrain", "mu_true", "context") if c not in log.columns]
    if not cols or missing:
        raise ValueError(f"{folder}/drive_log: lacks {missing or 'the feature columns f_*'}")
    t = log["t"].to_numpy(float)
    # A log row at t shows the frame of the latest camera tick strictly before t (row 0: the
    # first frame); the frame's id is logged on that same row.
    tick = np.maximum(np.ceil(t / camera_period_s - 1e-6).astype(int) - 1, 0)
    first = np.flatnonzero(np.r_[True, tick[1:] != tick[:-1]])
    offset_s = float(rates.get("clustering_frame_offset_s", 0.0))
    # The ground under the car when the frame was taken: the last row at or before its tick.
    at = np.clip(np.searchsorted(t, tick[first] * camera_period_s + 1e-9) - 1, 0, len(t) - 1)
    ctx = log["context"].to_numpy(float)
    return RunFrames(
        folder=folder,
        t_s=tick[first] * camera_period_s + offset_s,
        z=log[cols].to_numpy(float)[first],
        terrain=log["terrain"].astype(str).to_numpy()[at],
        mu=log["mu_true"].to_numpy(float)[at],
        speed_mps=log["v"].to_numpy(float)[at] if "v" in log.columns else None,
        logged=np.where(np.isfinite(ctx[first]), ctx[first], NOISE).astype(int),
        params=params,
        period_s=float(rates.get("recluster_period_s", 10.0)),
        strips=_strips(scenario.get("world"), folder),
        camera_period_s=camera_period_s,
        estimator=str(scenario.get("estimator", "")),
    )


@dataclass
class Replay:
    """Per-frame result of a replay."""

    ids: np.ndarray
    """(N,) context id given to each frame."""
    home: np.ndarray
    """(N,) majority terrain of that context just before the frame ('' for none or noise)."""
    evidence: np.ndarray
    """(N,) how each frame got its id (``ContextClusterer.last_evidence``)."""


def _composition(clusterer: ContextClusterer, terrain_at: dict[float, str]) -> dict:
    """Terrain counts of each context's stored frames, labelled as the last clustering left
    them (the frames a consumer such as the fitter relabels its samples by)."""
    labels = clusterer.frame_labels()
    comp: dict[int, Counter] = defaultdict(Counter)
    for t, k in zip(labels.t_s, labels.labels, strict=True):
        if k >= 0:
            comp[int(k)][terrain_at[float(t)]] += 1
    return comp


def replay(run: RunFrames) -> Replay:
    """The clustering system's call sequence replayed over the run's frames.

    A context's majority terrain before a frame counts the stored frames by their labels of the
    latest re-clustering plus the frames given the context since (a reservoir keeps a uniform
    sample of a context's frames, so the counts' proportions hold for long drives)."""
    clusterer = ContextClusterer(run.params)
    terrain_at = {float(t): str(n) for t, n in zip(run.t_s, run.terrain, strict=True)}
    ids = np.full(run.t_s.size, NOISE, dtype=int)
    home = np.full(run.t_s.size, "", dtype=object)
    evidence = np.full(run.t_s.size, "", dtype=object)
    comp: dict[int, Counter] = defaultdict(Counter)
    next_recluster_s = run.period_s
    speeds = [None] * run.t_s.size if run.speed_mps is None else run.speed_mps
    for i, (t, z) in enumerate(zip(run.t_s, run.z, strict=True)):
        while t > next_recluster_s + 1e-9:
            clusterer.recluster(next_recluster_s)
            comp = _composition(clusterer, terrain_at)
            next_recluster_s += run.period_s
        k, kept = clusterer.assign_frame(z, float(t), speeds[i])
        if kept:
            comp = _composition(clusterer, terrain_at)
        ids[i] = k
        evidence[i] = clusterer.last_evidence
        if k >= 0 and comp[k]:
            home[i] = comp[k].most_common(1)[0][0]
        if k >= 0 and not kept:
            comp[k][str(run.terrain[i])] += 1
    return Replay(ids=ids, home=home, evidence=evidence)


def _runs_of(mask: np.ndarray) -> np.ndarray:
    """Lengths of the unbroken runs of True in ``mask``."""
    edges = np.diff(np.r_[0, mask.astype(int), 0])
    return np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)


def score(run: RunFrames, result: Replay) -> dict:
    """The per-run measures of the module docstring for a replay's per-frame ids."""
    ids = result.ids
    dt = run.camera_period_s
    on_terrain = ~np.isin(run.terrain, run.strips)
    terrain_mu = {
        n: float(np.median(run.mu[run.terrain == n])) for n in np.unique(run.terrain)
    }  # fmt: skip
    home_mu = np.array([terrain_mu.get(h, -np.inf) for h in result.home])
    carried = home_mu > run.mu + CARRIED_TOL
    home_of = {}
    for k in np.unique(ids[(ids >= 0) & on_terrain]):
        names, counts = np.unique(run.terrain[(ids == k) & on_terrain], return_counts=True)
        home_of[int(k)] = names[counts.argmax()]
    given = (ids >= 0) & on_terrain
    own = np.array([home_of.get(int(k)) == n for k, n in zip(ids, run.terrain, strict=True)])
    name_s, reid_s, never, seen = [], [], 0, set()
    edges = np.flatnonzero(np.r_[True, run.terrain[1:] != run.terrain[:-1], True])
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        name = run.terrain[a]
        if not on_terrain[a]:
            continue
        hit = np.flatnonzero(own[a:b])
        if hit.size:
            (reid_s if name in seen else name_s).append(float(run.t_s[a + hit[0]] - run.t_s[a]))
        else:
            never += 1
        seen.add(name)
    named = np.zeros(ids.size, dtype=bool)
    for name in np.unique(run.terrain[on_terrain]):
        hit = np.flatnonzero(own & (run.terrain == name))
        if hit.size:
            named[hit[0] :] |= run.terrain[hit[0] :] == name
    runs = _runs_of(carried)
    n_terrain = int(on_terrain.sum())
    return {
        "carried_s": round(float(carried.sum() * dt), 2),
        "carried_terrain_s": round(float((carried & on_terrain).sum() * dt), 2),
        "longest_carried_s": round(float(runs.max(initial=0) * dt), 2),
        "carried_continued_s": round(
            float((carried & (result.evidence == "continued")).sum() * dt), 2
        ),
        "unexplained_frames": int(np.sum(result.evidence == "unexplained")),
        "purity": float(own[given].mean()) if given.any() else math.nan,
        "noise_fraction": float(np.mean(ids[on_terrain] < 0)) if n_terrain else math.nan,
        "known_noise_fraction": float(np.mean(ids[named] < 0)) if named.any() else math.nan,
        "name_s": name_s,
        "reid_s": reid_s,
        "visits_never_named": never,
        "n_contexts": int(np.unique(ids[ids >= 0]).size),
        "n_terrains": int(np.unique(run.terrain[on_terrain]).size),
    }


def replay_folder(folder: Path, settings: dict | None = None, speed: bool = True) -> dict:
    """Replay and score one run folder (``usable`` False with the reason when it cannot be),
    with the run's clustering settings changed by ``settings`` (field: value); ``speed`` False:
    no speed is passed to the clustering."""
    row: dict = {"run": str(folder)}
    try:
        run = load_run(folder)
        if settings:
            run = replace(run, params=replace(run.params, **settings))
        if not speed:
            run = replace(run, speed_mps=None)
    except (ValueError, TypeError) as err:
        return {**row, "usable": False, "reason": str(err)}
    start = time.perf_counter()
    result = replay(run)
    agreement = float(np.mean(result.ids == run.logged))
    return {
        **row,
        "usable": True,
        "estimator": run.estimator,
        "frames": int(result.ids.size),
        "strips": list(run.strips),
        "agreement": agreement,
        "replay_s": round(time.perf_counter() - start, 2),
        **score(run, result),
    }


def _summary(rows: list[dict]) -> dict:
    """Totals and extremes over runs."""
    if not rows:
        return {"runs": 0}
    carried = [r["carried_s"] for r in rows]
    worst = rows[int(np.argmax(carried))]
    name = [x for r in rows for x in r["name_s"]]
    reid = [x for r in rows for x in r["reid_s"]]

    def q(vals: list[float], p: float) -> float:
        return round(float(np.percentile(vals, p)), 2) if vals else math.nan

    return {
        "runs": len(rows),
        "carried_total_s": round(float(sum(carried)), 1),
        "carried_terrain_total_s": round(float(sum(r["carried_terrain_s"] for r in rows)), 1),
        "runs_with_carried_over_0.5s": int(sum(r["longest_carried_s"] > 0.5 for r in rows)),
        "longest_carried_s": max(r["longest_carried_s"] for r in rows),
        "worst_run": f"{'/'.join(Path(worst['run']).parts[-3:])} ({worst['carried_s']} s)",
        "purity_mean": round(float(np.mean([r["purity"] for r in rows])), 4),
        "noise_fraction_mean": round(float(np.mean([r["noise_fraction"] for r in rows])), 4),
        "known_noise_fraction_mean": round(
            float(np.nanmean([r["known_noise_fraction"] for r in rows])), 4
        ),
        "name_s_median": q(name, 50),
        "name_s_p90": q(name, 90),
        "name_s_max": q(name, 100),
        "reid_s_median": q(reid, 50),
        "reid_s_p90": q(reid, 90),
        "visits_never_named": int(sum(r["visits_never_named"] for r in rows)),
        "contexts_minus_terrains": int(sum(r["n_contexts"] - r["n_terrains"] for r in rows)),
    }


def _is_dev(run: str, dev: list[str]) -> bool:
    return any(run == d or run.startswith(d.rstrip("/") + "/") for d in dev)


def compare(
    before: Path, after: Path, dev: list[str], held_out: bool, known: list[Path] | None = None
) -> dict:
    """Before/after summaries over the runs whose replay is trusted in ``before`` (agreement 1.0
    with the code that ran them): the development set, and with ``held_out`` the rest. With
    ``known`` (result files of an earlier comparison) the rest is split: runs named in them are
    held out, the others are fresh."""
    a = {r["run"]: r for r in json.loads(before.read_text())["runs"]}
    b = {r["run"]: r for r in json.loads(after.read_text())["runs"]}
    trusted = sorted(k for k, r in a.items() if r.get("usable") and r["agreement"] == 1.0)
    missing = [k for k in trusted if not b.get(k, {}).get("usable")]
    if missing:
        raise ValueError(f"{after}: lacks trusted runs of {before}, e.g. {missing[0]}")
    seen = {r["run"] for f in known or [] for r in json.loads(f.read_text())["runs"]}
    groups = {"dev": [k for k in trusted if _is_dev(k, dev)]}
    rest = [k for k in trusted if not _is_dev(k, dev)]
    if held_out and known:
        groups["held_out"] = [k for k in rest if k in seen]
        groups["fresh"] = [k for k in rest if k not in seen]
    elif held_out:
        groups["held_out"] = rest
    return {
        name: {"before": _summary([a[k] for k in runs]), "after": _summary([b[k] for k in runs])}
        for name, runs in groups.items()
    }


def _print_compare(result: dict) -> None:
    for name, pair in result.items():
        print(f"\n## {name}: {pair['before']['runs']} runs")
        print("| measure | before | after |\n|---|---|---|")
        for key in pair["before"]:
            if key != "runs":
                print(f"| {key} | {pair['before'][key]} | {pair['after'][key]} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", type=Path, help="run folders or folders holding them")
    ap.add_argument("--out", type=Path, help="write the per-run results here (JSON)")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--dev", nargs="*", default=list(DEV_DEFAULT), help="the development set")
    ap.add_argument(
        "--held-out", action="store_true", help="--compare: also the runs outside --dev"
    )
    ap.add_argument(
        "--known",
        nargs="*",
        type=Path,
        help="--compare --held-out: result files whose runs are held out; the others are fresh",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="replay with this clustering setting changed (YAML value, e.g. "
        "continuation_hold_s=null); repeatable",
    )
    ap.add_argument(
        "--without-speed",
        action="store_true",
        help="pass no speed to the clustering (as the code before the blur rule)",
    )
    args = ap.parse_args(argv)
    settings = {}
    for item in args.set:
        field_name, eq, value = item.partition("=")
        if not eq:
            ap.error(f"--set {item!r}: expected FIELD=VALUE")
        settings[field_name.strip()] = yaml.safe_load(value)
    if args.compare:
        result = compare(*args.compare, dev=args.dev, held_out=args.held_out, known=args.known)
        _print_compare(result)
        if args.out:
            args.out.write_text(json.dumps(result, indent=1))
        return 0
    if not args.paths:
        ap.error("give run folders, or --compare BEFORE AFTER")
    rows = []
    for folder in run_folders(args.paths):
        row = replay_folder(folder, settings, speed=not args.without_speed)
        rows.append(row)
        if row["usable"]:
            print(
                f"{folder}: agreement {row['agreement']:.4f} carried {row['carried_s']} s "
                f"longest {row['longest_carried_s']} s, "
                f"noise {row['noise_fraction']:.3f}, purity {row['purity']:.3f}",
                flush=True,
            )
        else:
            print(f"{folder}: not usable: {row['reason']}", flush=True)
    if args.out:
        code = str(Path(clustering_module.__file__).resolve().parents[2])
        args.out.write_text(json.dumps({"code": code, "runs": rows}, indent=1))
    usable = [r for r in rows if r["usable"]]
    trusted = [r for r in usable if r["agreement"] == 1.0]
    print(f"{len(rows)} runs, {len(usable)} replayable, {len(trusted)} with agreement 1.0")
    return 0


if __name__ == "__main__":
    sys.exit(main())
