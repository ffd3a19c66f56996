"""``pcvfe simulate``: run the PC-VFE closed loop on a scenario and write a run folder.

The diagrams (pydrake) are imported inside :func:`run`, so importing this module (and the CLI)
does not import pydrake.
"""

from __future__ import annotations

import argparse
import math
import time
from datetime import datetime
from pathlib import Path

from pcvfe_drake.runs.friction_sources import ESTIMATORS, PCVFE_SOURCES
from pcvfe_drake.runs.scenario_files import DEFAULT_SCENARIO, shipped_scenarios

CHUNK_S = 1.0
"""Simulated time advanced per progress-bar step [s]."""


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="run the PC-VFE closed loop on a scenario (the main job of `make run`)",
        description=(
            "Simulate the closed loop (plant, downward camera, features, context clustering, "
            "context fitter, NMPC) on a scenario and write a run folder: the drive log "
            "(drive_log.csv, written as the run goes, plus camera frames), summary.json, "
            "playback.html (Meshcat recording, opens in a browser without a server) and "
            "figures/ (the paper's Fig. 4, 5 and 7). Ctrl-C stops cleanly and keeps what was "
            f"logged (so does SIGTERM). Shipped scenarios: {', '.join(shipped_scenarios())}."
        ),
    )
    parser.add_argument(
        "scenario",
        nargs="?",
        default=DEFAULT_SCENARIO,
        help=f"shipped scenario name or YAML file (default: {DEFAULT_SCENARIO})",
    )
    parser.add_argument(
        "--with",
        dest="overrides",
        action="append",
        default=[],
        type=Path,
        metavar="FILE",
        help="scenario YAML file applied on top of SCENARIO (repeatable, in order; it names only "
        "what it changes)",
    )
    parser.add_argument(
        "--out", type=_folder_arg, default=None, help="run folder (default: runs/<scenario>-<time>)"
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a run already in --out (removes its drive_log.csv, fitter_samples.npz, "
        "summary.json, playback.html, scenario.yaml, internal_error.txt, figures/ and frames/; "
        "other files stay); without it such a folder is refused",
    )
    length = parser.add_mutually_exclusive_group()
    length.add_argument("--laps", type=float, default=None, help="stop after N laps")
    length.add_argument("--duration", type=float, default=None, help="stop after S simulated s")
    parser.add_argument(
        "--meshcat",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="show the run in Meshcat (localhost) and save playback.html (default: on)",
    )
    parser.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    parser.add_argument(
        "--estimator",
        choices=ESTIMATORS,
        default=None,
        help="override the scenario's friction source (kmpc: the kinematic NMPC, no friction "
        "input)",
    )
    parser.add_argument(
        "--hardware",
        action="store_true",
        help=(
            "drive the car over LCM (the hardware station; rehearse with `pcvfe vehicle-bridge`) "
            "instead of simulating it; paced to wall-clock time; the loop's thread runs at "
            "the real-time priority hardware.control_priority when it is set"
        ),
    )
    parser.add_argument(
        "--lcm-url", default=None, help="with --hardware: LCM URL (default: the scenario's bus)"
    )
    parser.add_argument(
        "--no-progress", action="store_true", help="no progress bar (e.g. in CI logs)"
    )
    parser.set_defaults(func=run)


def _check_args(args: argparse.Namespace) -> None:
    if args.laps is not None and not (math.isfinite(args.laps) and args.laps > 0):
        raise ValueError(f"--laps must be a positive number, got {args.laps}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration must be a positive number of seconds, got {args.duration}")
    if args.seed is not None and args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")


def _folder_arg(text: str) -> Path:
    """``--out``'s folder; an empty one (an unset shell variable) would be the working
    directory, so it is refused."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty: give a run folder, or leave --out out for runs/")
    return Path(text)


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    import dataclasses

    from pcvfe_drake.diagrams.run_simulation import StartLocalMeshcat, run_simulation
    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.runs.run_folder import DEFAULT_RUNS_DIR, RunFolder, run_folder_name

    scenario = load_scenario(args.scenario, *args.overrides)
    if args.laps is not None or args.duration is not None:
        scenario = scenario.with_run_length(laps=args.laps, duration_s=args.duration)
    if args.seed is not None:
        scenario = dataclasses.replace(scenario, seed=args.seed)
    if args.estimator is not None:
        scenario = dataclasses.replace(scenario, estimator=args.estimator)
    scenario.validate(f"scenario {args.scenario!r}")  # with the command line's changes
    if args.hardware:  # a refused real-time priority stops here, before anything is written
        from pcvfe_drake.hardware.scheduling import check_control_priority

        check_control_priority(scenario.hardware.control_priority, "hardware.control_priority")
    tag = scenario.name
    if scenario.estimator != "pcvfe":
        tag += f"-{scenario.estimator}"
    out = args.out or DEFAULT_RUNS_DIR / run_folder_name(tag, datetime.now())
    folder = RunFolder(out)
    removed = folder.prepare(overwrite=args.overwrite)
    if removed:
        print(f"--overwrite: removed the previous run in {out}: {', '.join(removed)}")
    if scenario.estimator in PCVFE_SOURCES:  # the model as run, not where it was read from
        model = scenario.fit_config().model
        scenario = dataclasses.replace(
            scenario, fitter=dataclasses.replace(scenario.fitter, model=model)
        )
    folder.write_text(folder.scenario, scenario.to_yaml())

    meshcat = None
    if args.meshcat:
        meshcat = StartLocalMeshcat()
        print(f"Meshcat: {meshcat.web_url()} (localhost only)")

    station, realtime_rate, priority = None, None, 0
    if args.hardware:
        from pcvfe_drake.commands.vehicle_bridge import with_lcm_url
        from pcvfe_drake.diagrams.station import MakeVehicleStation

        scenario = with_lcm_url(scenario, args.lcm_url)
        folder.write_text(folder.scenario, scenario.to_yaml())
        hw = scenario.hardware
        print(f"hardware station on {hw.lcm_buses[hw.bus].lcm_url}")
        station = MakeVehicleStation(scenario, meshcat, hardware=True)
        realtime_rate = hw.realtime_rate
        priority = hw.control_priority
        if priority:
            print(f"control loop at SCHED_FIFO priority {priority} (hardware.control_priority)")
    elif args.lcm_url is not None:
        raise ValueError("--lcm-url needs --hardware")

    t0 = time.perf_counter()
    result = run_simulation(
        scenario,
        folder,
        meshcat=meshcat,
        progress=not args.no_progress,
        chunk_s=CHUNK_S,
        station=station,
        realtime_rate=realtime_rate,
        control_priority=priority,
    )
    from pcvfe_drake.runs.summary import summary_table

    print()
    print(summary_table(result.summary))
    print()
    print(f"run folder:   {out}")
    print(f"  drive log:  {folder.drive_log}")
    print(f"  summary:    {folder.summary}")
    if result.playback is not None:
        print(f"  playback:   {result.playback}  (open in a browser; no server needed)")
    for name, path in result.figures.items():
        print(f"  {name}: {path or '(not drawn: ' + result.figure_notes.get(name, '') + ')'}")
    if result.summary.get("error"):
        print(f"  the simulation stopped early: {result.summary['error']}")
    if result.log_errors:
        print(f"  note: {len(result.log_errors)} log chunk(s) rejected by the drive-log format")
    for message in result.write_errors:
        print(f"  not written: {message}")
    print(f"total {time.perf_counter() - t0:.1f} s")
    return run_exit_code(result, folder)


def run_exit_code(result, folder) -> int:
    """The exit status of a finished run, after reporting its internal errors on stderr:
    130 interrupted, :data:`pcvfe_drake.cli.INTERNAL_ERROR_EXIT` when writing its outputs failed
    in the project's own code, 1 when the simulation stopped on an error, else 0."""
    import sys

    from pcvfe_drake.cli import INTERNAL_ERROR_EXIT
    from pcvfe_drake.runs.run_folder import internal_error_report

    report = internal_error_report(result, folder)
    if report:
        print(report, file=sys.stderr)
    if result.summary.get("interrupted") or result.held_signals:
        return 130
    if result.internal_errors:
        return INTERNAL_ERROR_EXIT
    return 1 if result.summary.get("error") else 0
