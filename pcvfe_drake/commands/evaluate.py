"""``pcvfe evaluate``: a grid of runs (scenario x friction source x seed) on Dask, and its report.

The diagrams (pydrake) and Dask are imported inside :func:`run`, so importing this module (and
the CLI) imports neither.
"""

from __future__ import annotations

import argparse
import platform
import sys
from datetime import UTC, datetime
from pathlib import Path

from pcvfe_drake.evaluation.experiment import shipped_experiments


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "evaluate",
        help="compare friction sources over many seeds on Dask, with a report",
        description=(
            "Run every scenario x friction source x seed of an experiment file, each run one "
            "diagram simulation on a Dask worker (a local cluster by default, or an existing "
            "scheduler), store each result as it finishes (runs.parquet, laps.parquet, "
            "contexts.parquet, failures.parquet, runs/<run>/), and write report.md and "
            "report.html. Calling it again with the same --out skips the runs already done. "
            f"Shipped experiments: {', '.join(shipped_experiments()) or 'none'}."
        ),
    )
    parser.add_argument(
        "experiment", nargs="?", default=None, help="experiment YAML file or shipped name"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="results folder (default: runs/evaluate/<experiment>[-quick]); reused to resume",
    )
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--workers", type=int, default=None, help="local cluster of N worker processes"
    )
    where.add_argument(
        "--scheduler", default=None, help="address of a running Dask scheduler (tcp://HOST:8786)"
    )
    parser.add_argument("--seeds", type=int, default=None, help="number of seeds per cell")
    parser.add_argument(
        "--quick", action="store_true", help="the experiment's quick settings (few seeds, short)"
    )
    parser.add_argument(
        "--report",
        type=Path,
        default=None,
        metavar="DIR",
        help="only rebuild report.md / report.html of a results folder (no runs)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def _environment() -> dict:
    from pcvfe_drake.diagrams.evaluate_run import package_versions

    return {
        "command": " ".join(sys.argv),
        "started_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "client_host": platform.node(),
        "client_versions": package_versions(),
    }


def run(args: argparse.Namespace) -> int:
    from pcvfe_drake.evaluation.report import build_report

    if args.report is not None:
        if args.experiment is not None:
            raise ValueError("--report DIR rebuilds a report; give no experiment with it")
        md, html = build_report(args.report)
        print(f"report: {md}\n        {html}")
        return 0
    if args.experiment is None:
        raise ValueError("give an experiment file (or --report DIR)")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")

    from pcvfe_drake.diagrams.experiment_io import load_experiment, run_specs
    from pcvfe_drake.evaluation.runner import open_client, run_sweep
    from pcvfe_drake.evaluation.store import ResultStore

    exp, path = load_experiment(args.experiment)
    out = args.out or Path("runs") / "evaluate" / (exp.name + ("-quick" if args.quick else ""))
    specs = run_specs(
        exp, path, seeds=args.seeds, quick=args.quick, worlds_dir=out / "worlds", progress=True
    )
    store = ResultStore(out)
    as_run = exp.to_dict()
    as_run["seeds"] = len({s.seed for s in specs})
    if args.quick:
        as_run["duration_s"], as_run["laps"] = exp.quick.duration_s, None
    store.start(as_run, _environment())
    pending = store.pending(specs)
    where = f"scheduler {args.scheduler}" if args.scheduler else "a local Dask cluster"
    print(
        f"{exp.name}: {len(specs)} runs ({len(specs) - len(pending)} already done in {out}); "
        f"{len(pending)} to run on {where}"
    )
    stats = None
    if pending:
        with open_client(args.workers, args.scheduler) as client:
            stats = run_sweep(specs, store, client, progress=not args.no_progress)
        for run_id, error in stats.failures:
            print(f"  failed: {run_id}: {error}")
    md, html = build_report(out)
    print(f"results: {out}\nreport:  {md}\n         {html}")
    if stats is not None and stats.interrupted:
        print("interrupted: finished runs are stored; run the same command again to resume")
        return 130
    return 1 if stats is not None and stats.failed else 0
