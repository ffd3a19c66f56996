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
        "--sources",
        nargs="+",
        default=None,
        metavar="NAME",
        help="run only these friction sources of the experiment",
    )
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
    more = parser.add_argument_group(
        "with --report: more tables of the stored runs (each written beside report.md)"
    )
    more.add_argument(
        "--entry-latency",
        action="store_true",
        help="per terrain entry: seconds to the context's id, first fit, mu within 0.05 "
        "(entry_latency.md/.json)",
    )
    more.add_argument(
        "--against",
        metavar="SOURCE",
        default=None,
        help="with --entry-latency: seconds lost per terrain to this source's run of each seed",
    )
    more.add_argument(
        "--interval-coverage",
        action="store_true",
        help="refit each context's final buffer and count how often the 95 %% intervals hold "
        "the truth (interval_coverage.md/.json)",
    )
    more.add_argument(
        "--calibrate",
        nargs="?",
        const="effects",
        choices=("effects", "st", "live"),
        default=None,
        help="with --interval-coverage: choose the model-error budget on the calibration seeds "
        "(fits of this kind, default effects), then score every seed with it",
    )
    more.add_argument(
        "--calibration-seeds", default="0-4", help="seeds to calibrate on, e.g. 0-4 (default)"
    )
    more.add_argument(
        "--target", type=float, default=0.9, help="with --calibrate: share of pairs to cover"
    )
    more.add_argument(
        "--model-error-rel", type=float, default=0.0, help="the budget to score (no --calibrate)"
    )
    more.add_argument(
        "--two-sided",
        action="store_true",
        help="two-sided intervals also where the data never came near the limit",
    )
    more.add_argument(
        "--results-page",
        type=Path,
        default=None,
        metavar="PAGE",
        help="also write (or update) this experiment's section of a results page, e.g. "
        "docs/results.md",
    )
    parser.set_defaults(func=run)


def _environment() -> dict:
    from pcvfe_drake.diagrams.evaluate_run import package_versions

    return {
        "command": " ".join(sys.argv),
        "started_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "client_host": platform.node(),
        "client_versions": package_versions(),
    }


def _report(args: argparse.Namespace) -> int:
    """``--report DIR`` and the tables that go with it."""
    from pcvfe_drake.evaluation.report import build_report

    if args.against is not None and not args.entry_latency:
        raise ValueError("--against goes with --entry-latency")
    if args.calibrate is not None and not args.interval_coverage:
        raise ValueError("--calibrate goes with --interval-coverage")
    md, html = build_report(args.report)
    print(f"report: {md}\n        {html}")
    if args.entry_latency:
        from pcvfe_drake.evaluation.entry_latency import write_entry_latency

        json_path, md_path, text = write_entry_latency(args.report, args.against)
        print(f"\n{text}\nentry latency: {md_path}\n               {json_path}")
    if args.interval_coverage:
        from pcvfe_drake.evaluation.interval_coverage import write_interval_coverage

        json_path, md_path, text = write_interval_coverage(
            args.report,
            calibration_seeds=args.calibration_seeds,
            model_error_rel=args.model_error_rel,
            calibrate_on=args.calibrate,
            target=args.target,
            two_sided=args.two_sided,
        )
        print(f"\n{text}\ninterval coverage: {md_path}\n                   {json_path}")
    if args.results_page is not None:
        from pcvfe_drake.evaluation.results_page import update_results_page

        page = update_results_page(args.results_page, [args.report])
        print(f"results page: {page}")
    return 0


def run(args: argparse.Namespace) -> int:
    from pcvfe_drake.evaluation.report import build_report

    extras = [
        flag
        for flag, given in (
            ("--entry-latency", args.entry_latency),
            ("--interval-coverage", args.interval_coverage),
            ("--results-page", args.results_page is not None),
        )
        if given
    ]
    if args.report is not None:
        if args.experiment is not None:
            raise ValueError("--report DIR rebuilds a report; give no experiment with it")
        return _report(args)
    if extras:
        raise ValueError(f"{', '.join(extras)} go with --report DIR (the stored runs)")
    if args.experiment is None:
        raise ValueError("give an experiment file (or --report DIR)")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")

    from pcvfe_drake.diagrams.experiment_io import load_experiment, run_specs
    from pcvfe_drake.evaluation.runner import open_client, run_sweep
    from pcvfe_drake.evaluation.store import ResultStore

    exp, path = load_experiment(args.experiment)
    if args.sources:
        exp = exp.with_sources(args.sources)
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
