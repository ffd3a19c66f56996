"""Run a folder of check scripts and collect the JSON each prints last (``make bench``,
``make validate``; no pydrake).

Every ``<folder>/<name>.py`` except ``run_all.py`` and ``_``-prefixed files is run with the same
Python interpreter from the repository root, with ``--quick`` passed through when asked; its
output is echoed with a ``[name]`` prefix, and the JSON object on its last non-empty stdout line
is its result. A script that fails, times out or prints no JSON object gets
``{"error": ..., "returncode": ...}``: the last line is the contract, so that the collected
results never depend on parsing a script's prose.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path


def discover(folder: Path, only: list[str] | None = None) -> list[Path]:
    """The scripts of ``folder`` (sorted), or those named in ``only`` (SystemExit naming any
    unknown)."""
    scripts = sorted(
        p for p in folder.glob("*.py") if p.name != "run_all.py" and not p.name.startswith("_")
    )
    if only:
        known = {p.stem: p for p in scripts}
        unknown = [n for n in only if n not in known]
        if unknown:
            raise SystemExit(
                f"run_all: unknown script(s) {unknown} in {folder}; have {sorted(known)}"
            )
        scripts = [known[n] for n in only]
    return scripts


def last_json(lines: list[str]) -> dict:
    """The JSON object on the last non-empty line (ValueError when there is none)."""
    last = next((ln for ln in reversed(lines) if ln.strip()), "")
    try:
        result = json.loads(last)
    except ValueError as exc:
        raise ValueError(f"no JSON object on the last stdout line: {last[-200:]!r}") from exc
    if not isinstance(result, dict):
        raise ValueError(f"the last stdout line is JSON but not an object: {last[-200:]!r}")
    return result


def run_script(script: Path, quick: bool, timeout_s: float, cwd: Path) -> tuple[dict, float]:
    """Run one script; returns its result (or an error record) and its wall time [s]."""
    cmd = [sys.executable, str(script)] + (["--quick"] if quick else [])
    name = script.stem
    t0 = time.perf_counter()
    lines: list[str] = []
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=cwd)
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
    try:
        result = last_json(lines)
    except ValueError as exc:
        return {"error": str(exc), "returncode": proc.returncode}, wall
    if proc.returncode != 0:
        result = {"error": f"exit code {proc.returncode}", "returncode": proc.returncode, **result}
    return result, wall


def run_suite(
    folder: Path,
    *,
    quick: bool,
    only: list[str] | None,
    timeout_s: float,
    out: Path,
    headline: Callable[[dict], str],
    failed: Callable[[dict], bool],
) -> int:
    """Run every script of ``folder``, write ``{name: result}`` to ``out`` after each one (what
    has finished survives an interruption), print a table of ``headline(result)``; returns 1
    if any result is an error or ``failed(result)``, else 0."""
    results: dict[str, dict] = {}
    walls: dict[str, float] = {}
    for script in discover(folder, only):
        print(f"=== {script.stem} {'(quick)' if quick else ''}", flush=True)
        results[script.stem], walls[script.stem] = run_script(
            script, quick, timeout_s, folder.parent
        )
        out.write_text(json.dumps(results, indent=2) + "\n")
    width = max((len(n) for n in results), default=10)
    print()
    print(f"{'script':<{width}}  {'wall s':>7}  result")
    for name, result in results.items():
        text = f"ERROR: {result['error']}" if "error" in result else headline(result)
        print(f"{name:<{width}}  {walls[name]:7.1f}  {text}")
    print(f"results: {out}")
    return 1 if any("error" in r or failed(r) for r in results.values()) else 0
