"""Run every accuracy check in this folder against its target (``make validate``).

A validation script checks that a part of the product is accurate enough (a fit, a lap, the
workbench's loop, input validation) and prints one JSON object on its last stdout line with
``target`` (what it checks, in words) and ``passed`` (true / false; absent when it was skipped,
e.g. no Chromium for the playback check). Each ``validation/<name>.py`` is run with ``--quick``
passed through; the results are collected into ``validation/results.json`` and a PASS / FAIL /
SKIPPED table is printed at the end. The exit code is 1 if any check failed or broke.

Usage: python validation/run_all.py [--quick] [--only NAME ...] [--timeout S]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcvfe_drake.evaluation.suite import run_suite

HERE = Path(__file__).resolve().parent


def verdict(result: dict) -> str:
    """``PASS``, ``FAIL`` or ``SKIPPED`` with the target (a result without a verdict is FAIL:
    a check that cannot say whether it passed has not passed)."""
    target = result.get("target", "(no target stated)")
    if result.get("skipped"):
        return f"SKIPPED ({result.get('reason', '')}): {target}"
    passed = result.get("passed")
    return f"{'PASS' if passed is True else 'FAIL'}: {target}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="pass --quick to every check")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="run only these checks")
    parser.add_argument("--timeout", type=float, default=3600.0, help="per-check wall limit [s]")
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
        headline=verdict,
        failed=lambda result: verdict(result).startswith("FAIL"),
    )


if __name__ == "__main__":
    sys.exit(main())
