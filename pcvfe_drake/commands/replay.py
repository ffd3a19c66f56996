"""``pcvfe replay``: rerun the estimator on a recorded drive (a run folder or a drive log).

pydrake is imported inside :func:`run`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "replay",
        help="rerun perception and estimation on a recorded drive (run folder or drive log)",
        description=(
            "Play a recorded drive out of the replay station (the station's ports: state, "
            "camera frames, and the input recorded with them) through the same features, "
            "clustering, fitter and NMPC as `simulate`, and write a run folder like it. SOURCE "
            "is a run folder of `pcvfe simulate` / `pcvfe replay` (its scenario.yaml is used) "
            "or a drive log file, e.g. from `pcvfe import-bag` (give --scenario). A run replays "
            "to the same context ids when its drive log holds the features of every camera frame "
            "(a run folder's does, at the default rates), and to the same estimates when it "
            "also logged at the fitter's sampling rate (docs/hardware.md). A replay that stops "
            "early says why on stderr and exits 1."
        ),
    )
    parser.add_argument("source", type=Path, help="run folder or drive log (.csv/.parquet)")
    parser.add_argument("--out", type=Path, required=True, help="run folder to write")
    parser.add_argument(
        "--scenario",
        default=None,
        help="scenario (name or YAML) for a drive-log SOURCE (default: the run folder's)",
    )
    parser.add_argument(
        "--meshcat", action="store_true", help="show the replay in Meshcat (localhost)"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pcvfe_drake.commands.simulate import run_exit_code
    from pcvfe_drake.diagrams.replay_station import MakeReplayStation
    from pcvfe_drake.diagrams.run_simulation import RunFolder, StartLocalMeshcat, run_simulation
    from pcvfe_drake.diagrams.scenario_io import load_scenario, save_scenario
    from pcvfe_drake.hardware.replay import ReplayLog
    from pcvfe_drake.runs.summary import summary_table

    source: Path = args.source
    if source.is_dir():
        scenario = load_scenario(args.scenario or source / "scenario.yaml")
        log = ReplayLog.from_run_folder(source, scenario.rates.camera_period_s)
    elif source.is_file():
        if args.scenario is None:
            raise ValueError(
                f"replay {source}: a drive-log source needs --scenario (vehicle, rates)"
            )
        scenario = load_scenario(args.scenario)
        log = ReplayLog.from_drive_log(source)
    else:
        raise FileNotFoundError(f"replay: {source} is neither a run folder nor a drive log")
    scenario = scenario.with_run_length(duration_s=log.duration_s)
    rates = scenario.rates
    fidelity = log.fidelity(rates.fitter_sample_period_s, rates.camera_period_s)
    if not fidelity["exact"]:
        print(
            "replay: not an exact rerun of the recording (docs/hardware.md, Replay):\n  "
            + "\n  ".join(fidelity["reasons"])
        )
    if args.out.resolve() == source.resolve():
        raise ValueError("replay: --out must not be the source run folder")
    args.out.mkdir(parents=True, exist_ok=True)
    save_scenario(scenario, args.out / "scenario.yaml")
    (args.out / "replay.json").write_text(
        json.dumps({"source": str(source), **fidelity}, indent=2) + "\n"
    )
    meshcat = StartLocalMeshcat() if args.meshcat else None
    t0 = time.perf_counter()
    result = run_simulation(
        scenario,
        RunFolder(args.out),
        meshcat=meshcat,
        progress=not args.no_progress,
        station=MakeReplayStation(scenario, log),
    )
    error = result.summary.get("error")
    print()
    if error:
        print(f"PARTIAL REPLAY: stopped at t = {result.summary.get('sim_time_s', 0.0):.2f} s of "
              f"{log.duration_s:.2f} s; the summary covers only that part")  # fmt: skip
    print(summary_table(result.summary))
    print(f"\nreplayed {source} ({log.duration_s:.2f} s, {len(log.frame_paths)} frames, "
          f"features from the {fidelity['features']}) into {args.out} in "
          f"{time.perf_counter() - t0:.1f} s")  # fmt: skip
    if error:
        print(f"pcvfe replay: error: the replay of {source} stopped early: {error}",
              file=sys.stderr)  # fmt: skip
    return run_exit_code(result, RunFolder(args.out))
