"""Run every benchmark in this folder and collect their results (``make bench``).

A benchmark times a product claim against a baseline (or a peer package) measured in the same
run and prints one JSON object on its last stdout line, with its ratio. Each
``benchmarks/<name>.py`` is run with ``--quick`` passed through; the results are collected into
``benchmarks/results.json`` (``{name: result}``) and a table of the headline figures (keys naming
a speed-up, ratio, real-time factor, time or rate) is printed at the end. The exit code is 1 if
any benchmark failed.

Usage: python benchmarks/run_all.py [--quick] [--only NAME ...] [--timeout S]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcvfe_drake.evaluation.suite import run_suite

HERE = Path(__file__).resolve().parent
HEADLINE_WORDS = ("speedup", "ratio", "realtime_factor", "per_", "_ms", "rate")


def headline(result: dict) -> str:
    items = [
        f"{k}={v}"
        for k, v in result.items()
        if isinstance(v, int | float)
        and not isinstance(v, bool)
        and any(w in k for w in HEADLINE_WORDS)
    ]
    return ", ".join(items[:6]) or "(no headline figures)"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="pass --quick to every benchmark")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="run only these benchmarks")
    parser.add_argument(
        "--timeout", type=float, default=1800.0, help="per-benchmark wall-clock limit [s]"
    )
    parser.add_argument(
        "--out", type=Path, default=HERE / "results.json", help="where to write the results"
    )
    args = parser.parse_args()
    return run_suite(
        HERE,
        quick=args.quick,
        only=args.only,
        timeout_s=args.timeout,
        out=args.out,
        headline=headline,
        failed=lambda result: False,
    )


if __name__ == "__main__":
    sys.exit(main())
