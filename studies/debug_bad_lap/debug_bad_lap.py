"""A bad lap, seen through the Meshcat debugging layers (the walk-through of docs/simulation.md).

Runs a scenario whose NMPC is given an optimistic fixed friction (``estimator: fixed`` with
``fixed.use: nominal``, the vehicle's nominal mu, where the scenario supports friction sources;
by default ``paper_eval``) until the car leaves the course (the scenario's ``stop_on_failure``),
then reruns the same scenario and seed to ``--before`` seconds before that instant and takes a
headless-Chromium screenshot of each run's playback on its last frame, aimed at the car (plan,
friction circle, camera panel) and at the feature cloud. The screenshots go to ``--out-dir``.
With ``--quick`` only the failing run (no screenshots).

Usage: python studies/debug_bad_lap/debug_bad_lap.py [--quick] [--scenario NAME] [--out-dir DIR]
       [--before S ...]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from pcvfe_drake.views.browser import find_chromium, screenshot

CAR_OFFSET = np.array([-7.0, 0.0, 9.0])  # FrictionCircleView's default offset from the car


def optimistic(scenario):
    """The scenario with the optimistic fixed friction, or a ValueError naming what is missing."""
    if not hasattr(scenario, "estimator") or not hasattr(scenario, "fixed"):
        raise ValueError(
            f"scenario {scenario.name!r} has no friction-source fields (estimator, fixed): "
            "this check needs the friction sources of the scenario"
        )
    scenario.estimator = "fixed"
    scenario.fixed.use = "nominal"
    return scenario


def run(scenario, folder: Path, duration_s: float | None):
    from pcvfe_drake.diagrams.run_simulation import RunFolder, StartLocalMeshcat, run_simulation

    if duration_s is not None:
        scenario = scenario.with_run_length(duration_s=duration_s)
    meshcat = StartLocalMeshcat()
    result = run_simulation(scenario, RunFolder(folder), meshcat=meshcat, progress=False)
    return result.summary, meshcat


def shoot(chromium: str, meshcat, html: Path, png: Path, target, back) -> bool:
    """Screenshot of the playback on its last frame, looking at ``target`` from ``back``."""
    from pydrake.geometry import MeshcatAnimation

    recording = meshcat.get_mutable_recording()
    recording.set_loop_mode(MeshcatAnimation.LoopMode.kLoopOnce)
    recording.set_clamp_when_finished(True)
    meshcat.PublishRecording()
    target = np.asarray(target, dtype=float)
    meshcat.SetCameraPose(target + np.asarray(back, dtype=float), target)
    html.write_text(meshcat.StaticHtml())
    return any(screenshot(chromium, html, png, wait_ms=90000) for _ in range(2))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="the failing run only")
    parser.add_argument("--scenario", default="paper_eval")
    parser.add_argument("--out-dir", type=Path, default=None, help="where the screenshots go")
    parser.add_argument("--before", type=float, nargs="+", default=[2.0, 1.0, 0.0])
    args = parser.parse_args()

    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.systems.meshcat_layer import packed_translation

    out = {"benchmark": "debug_bad_lap", "scenario": args.scenario}
    try:
        scenario = optimistic(load_scenario(args.scenario))
    except (ValueError, FileNotFoundError) as exc:
        out.update(skipped=True, reason=str(exc))
        print(json.dumps(out))
        return 0
    with tempfile.TemporaryDirectory(prefix="pcvfe_bad_lap_") as tmp:
        tmp = Path(tmp)
        print(f"{args.scenario} with an optimistic fixed friction, until it fails ...", flush=True)
        summary, _ = run(scenario, tmp / "full", None)
        t_end = float(summary["sim_time_s"])
        events = summary.get("failure_events") or []
        out.update(
            sim_time_s=t_end,
            stop_reason=summary.get("stop_reason"),
            first_failure=events[0] if events else None,
            catastrophic_failures=summary.get("catastrophic_failures"),
            nmpc_fallbacks=summary.get("nmpc_fallbacks"),
        )
        print(f"  ended at {t_end:.2f} s: {out['first_failure']}", flush=True)
        chromium = find_chromium()
        if args.quick or chromium is None or args.out_dir is None:
            out["screenshots"] = "skipped (--quick, no --out-dir, or no chromium)"
            print(json.dumps(out))
            return 0
        args.out_dir.mkdir(parents=True, exist_ok=True)
        shots = []
        for before in args.before:
            t = max(0.5, t_end - before)
            print(f"rerun to {t:.2f} s ({before:.1f} s before the end) ...", flush=True)
            part, meshcat = run(scenario, tmp / f"to_{t:.2f}", t)
            car = packed_translation(meshcat, "/pcvfe/friction_circle") - CAR_OFFSET
            look_at = car + [0.0, 0.0, 7.0]  # between the car and the panels above it
            png = args.out_dir / f"bad_lap_{before:.0f}s_before.png"
            ok = shoot(chromium, meshcat, tmp / "car.html", png, look_at, (0.0, -30.0, 12.0))
            entry = {"before_s": before, "t_s": t, "car": png.name if ok else None}
            anchor = packed_translation(meshcat, "/pcvfe/features/current")
            if anchor is not None and before == args.before[-1]:
                png = args.out_dir / "bad_lap_features.png"
                ok = shoot(chromium, meshcat, tmp / "f.html", png, anchor, (0.0, -45.0, 25.0))
                entry["features"] = png.name if ok else None
            shots.append(entry)
            print(f"  {entry}", flush=True)
        out["screenshots"] = shots
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
