"""Run every benchmark in this folder and collect their results.

Each ``benchmarks/<name>.py`` (except this file) is run with the same Python interpreter, with
``--quick`` passed through; its progress is echoed with a ``[name]`` prefix, and the JSON object
on its last stdout line is collected into ``benchmarks/results.json`` (``{name: result}``; a
benchmark that fails or prints no JSON gets ``{"error": ..., "returncode": ...}``). A summary
table of the headline figures (keys naming a speed-up, ratio or real-time factor) is printed at
the end. The exit code is 1 if any benchmark failed.

Usage: python benchmarks/run_all.py [--quick] [--only NAME ...] [--timeout S]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
HEADLINE_WORDS = ("speedup", "ratio", "realtime_factor", "per_", "_ms", "rate")


def discover(only: list[str] | None) -> list[Path]:
    scripts = sorted(
        p for p in HERE.glob("*.py") if p.name != Path(__file__).name and not p.name.startswith("_")
    )
    if only:
        known = {p.stem: p for p in scripts}
        unknown = [n for n in only if n not in known]
        if unknown:
            raise SystemExit(f"run_all: unknown benchmark(s) {unknown}; have {sorted(known)}")
        scripts = [known[n] for n in only]
    return scripts


def run_one(script: Path, quick: bool, timeout_s: float) -> tuple[dict, float]:
    cmd = [sys.executable, str(script)] + (["--quick"] if quick else [])
    name = script.stem
    t0 = time.perf_counter()
    lines: list[str] = []
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=HERE.parent)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            print(f"[{name}] {line}", end="", flush=True)
            if time.perf_counter() - t0 > timeout_s:
                proc.kill()
                break
        proc.wait(timeout=max(1.0, timeout_s - (time.perf_counter() - t0)))
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    wall = time.perf_counter() - t0
    if wall > timeout_s:
        return {"error": f"timed out after {timeout_s:g} s", "returncode": proc.returncode}, wall
    last = next((ln for ln in reversed(lines) if ln.strip()), "")
    try:
        result = json.loads(last)
        if not isinstance(result, dict):
            raise ValueError("not a JSON object")
    except ValueError:
        return {
            "error": f"no JSON object on the last stdout line: {last[-200:]!r}",
            "returncode": proc.returncode,
        }, wall
    if proc.returncode != 0:
        result = {"error": f"exit code {proc.returncode}", "returncode": proc.returncode, **result}
    return result, wall


def headline(result: dict) -> str:
    if "error" in result:
        return f"ERROR: {result['error']}"
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

    results: dict[str, dict] = {}
    walls: dict[str, float] = {}
    for script in discover(args.only):
        print(f"=== {script.stem} {'(quick)' if args.quick else ''}", flush=True)
        results[script.stem], walls[script.stem] = run_one(script, args.quick, args.timeout)
        args.out.write_text(json.dumps(results, indent=2) + "\n")  # keep what we have so far

    width = max(len(n) for n in results) if results else 10
    print()
    print(f"{'benchmark':<{width}}  {'wall s':>7}  headline")
    for name, result in results.items():
        print(f"{name:<{width}}  {walls[name]:7.1f}  {headline(result)}")
    print(f"results: {args.out}")
    return 1 if any("error" in r for r in results.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
