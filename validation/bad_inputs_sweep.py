"""Bad and unusual inputs through the ``pcvfe`` CLI, as a new user would give them: does every
one end in a named error (or the documented degraded behaviour), never a traceback, a hang, a
silently wrong result or lost data?

The cases (``validation/_bad_inputs_cases.py``; the ``_`` keeps ``run_all.py`` from running it
as a check) follow the categories of the project's first bad-input sweep, with at least its
attempts per category. Each runs ``pcvfe ...`` through
``pcvfe_drake.cli.main`` in this process (``--subprocess``: in a fresh interpreter, as a user's
shell would) with a timeout and a cap on memory, in a scratch folder with its own fixtures: a
short run folder of ``paper_sim`` (2.5 s), a small results folder of ``pcvfe evaluate`` (written
through ``ResultStore``, no runs), a small ROS 2 bag (``tests/bag_writer.py``) and a drive log.
A case expects ``error`` (refused: exit 2 with a ``pcvfe CMD: error:`` line naming the file and
field it lists), ``stopped`` (began, then stopped early: exit 1 with that line) or ``ok``
(accepted, maybe degraded: exit 0), and may check what was written or printed. Outcomes:

- ``named``: refused as expected, the error line naming what the case lists;
- ``degraded``: accepted (or stopped early) as documented, its outputs there;
- ``traceback``: stderr holds a Python traceback;
- ``internal``: exit 70, the CLI's internal error (a bug, said as such);
- ``hang``: the timeout ran out (``--timeout``), or unbounded work: a MemoryError under the
  sweep's memory cap (``--memory-gb``), more than ``MAX_WRITTEN_MB`` written, or the process grown
  by more than ``MAX_GROWTH_MB``;
- ``wrong``: silently wrong: a refusal that was accepted, an accepted input that was refused, or
  a result that says what it should not;
- ``lost``: data lost: an output the run should have written is missing or unreadable;
- ``vague``: refused, but the error line does not name the file or the field.

Usage: python validation/bad_inputs_sweep.py [--only CATEGORY] [--match TEXT] [--quick]
       [--timeout S] [--memory-gb GB] [--keep DIR] [--subprocess] [--verbose]
Prints one table per category (with each case that is neither ``named`` nor ``degraded``), then
one JSON object (target, passed, counts, rows).
"""

from __future__ import annotations

import argparse
import collections
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _bad_inputs_cases import (  # beside this script (the suite skips _-prefixed files)
    PCVFE,
    Case,
    cases,
    make_bag,
    make_log,
    make_results,
    make_run,
    more_cases,
)

# ----------------------------------------------------------------------------- running
OUTCOMES = ("named", "degraded", "traceback", "internal", "hang", "wrong", "lost", "vague")
"""``named``: refused with one error line; ``degraded``: accepted (or stopped early) as
documented; ``hang``: past the timeout, or unbounded (more than ``MAX_WRITTEN_MB`` written, or
the process grew by more than ``MAX_GROWTH_MB``); ``wrong``: silently wrong (nonsense accepted, a
good input refused, a wrong result); ``lost``: data lost (an output that should be there is not);
``vague``: refused, but the error line does not name the file or field."""

MAX_WRITTEN_MB = 100.0
"""More than this written under a case's scratch folder is unbounded work [MB]."""

MAX_GROWTH_MB = 3000.0
"""More than this growth of the sweep's peak memory during one case is unbounded work [MB]."""


def classify(case: Case, code: int | None, err: str, says: tuple[str, ...] = ()) -> str:
    if code is None:
        return "hang"
    if "MemoryError" in err or "Cannot allocate memory" in err:
        return "hang"  # unbounded: it asked for more memory than the sweep allows
    if "Traceback (most recent call last)" in err:
        return "traceback"
    if code == 70:
        return "internal"
    if case.expect == "error":
        if not (code == 2 and ": error: " in err):
            return "wrong"
        line = next((x for x in err.splitlines() if ": error: " in x), "")
        return "named" if all(w in line for w in says) else "vague"
    if case.expect == "stopped":  # began, then stopped early: exit 1 with the reason
        return "degraded" if code == 1 and ": error: " in err else "wrong"
    return "degraded" if code == 0 else "wrong"


class _Timeout(BaseException):
    """Raised by the alarm: past every ``except Exception`` of the CLI, as a hang."""


def _in_process(args: list[str], cwd: Path, timeout_s: float) -> tuple[int | None, str, str]:
    """``pcvfe_drake.cli.main(args)`` in this process (no interpreter start per case), in
    ``cwd``, its stdout and stderr captured; an exception that escapes the CLI is printed as a
    traceback; a SIGALRM after ``timeout_s`` ends it as a hang (exit None)."""
    import contextlib
    import signal
    import traceback

    from pcvfe_drake.cli import main as cli_main

    def alarm(signum, frame):
        raise _Timeout

    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    try:
        os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli_main(args)
            except SystemExit as exc:  # argparse
                code = exc.code if isinstance(exc.code, int) else 2
            except _Timeout:
                code = None
            except Exception:  # noqa: BLE001 - escaped the CLI: that is a traceback
                traceback.print_exc()
                code = 1
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        os.chdir(here)
    return code, out.getvalue(), err.getvalue()


def _peak_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _written_mb(folder: Path) -> float:
    total = 0
    for root, _, names in os.walk(folder):
        for n in names:
            try:
                total += os.lstat(os.path.join(root, n)).st_size
            except OSError:
                pass
    return total / 1e6


def _writable_again(folder: Path) -> None:
    """Undo the read-only folders of a case (``chattr +i``), so that it can be removed."""
    subprocess.run(["chattr", "-R", "-i", str(folder)], capture_output=True)
    for root, dirs, _ in os.walk(folder):
        for d in dirs:
            os.chmod(os.path.join(root, d), 0o755)


def run_case(
    case: Case, work: Path, fixtures: dict, timeout_s: float, in_process: bool = True
) -> dict:
    tmp = Path(tempfile.mkdtemp(dir=work))
    for rel, text in case.files.items():
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            (tmp / rel).write_bytes(text)
        else:
            (tmp / rel).write_text(text)
    if case.prepare is not None:
        case.prepare(tmp)
    names = {"tmp": str(tmp), "log": str(fixtures.get("log", ""))}
    if case.damage is not None:
        source, damage = case.damage
        copy = tmp / f"copy_{source}"
        if Path(fixtures[source]).is_dir():
            shutil.copytree(fixtures[source], copy)
        else:
            copy = copy.with_suffix(Path(fixtures[source]).suffix)
            shutil.copy2(fixtures[source], copy)
        damage(copy)
        names["copy"] = str(copy)
    args = [a.format(**names) for a in case.args]
    says = tuple(w.format(**names) for w in case.says)
    t0 = time.perf_counter()
    peak0 = _peak_mb()
    if in_process:
        code, out, err = _in_process(args, tmp, timeout_s)
    else:
        try:
            done = subprocess.run(
                [*PCVFE, *args], capture_output=True, text=True, timeout=timeout_s, cwd=tmp
            )
            code, out, err = done.returncode, done.stdout, done.stderr
        except subprocess.TimeoutExpired as exc:
            code, out = None, ""
            err = (exc.stderr or b"").decode(errors="replace")
    seconds = time.perf_counter() - t0
    outcome, why = classify(case, code, err, says), ""
    written, growth = _written_mb(tmp), _peak_mb() - peak0
    if outcome in ("named", "degraded") and (written > MAX_WRITTEN_MB or growth > MAX_GROWTH_MB):
        outcome, why = "hang", f"unbounded: {written:.0f} MB written, memory +{growth:.0f} MB"
    if outcome in ("named", "degraded") and case.check is not None:
        found = case.check(tmp, out, err)
        if found is not None:
            outcome, why = found
    _writable_again(tmp)
    shutil.rmtree(tmp, ignore_errors=True)
    last = err.strip().splitlines()[-1] if err.strip() else ""
    return {
        "category": case.category,
        "case": case.name,
        "expect": case.expect,
        "exit": code,
        "outcome": outcome,
        "why": why,
        "seconds": round(seconds, 1),
        "stderr_last_line": last[:300],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default=None, help="run one category (by its name)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="the first two cases of each category (a look at every category in a minute)",
    )
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds per case")
    parser.add_argument("--keep", type=Path, default=None, help="scratch folder to keep")
    parser.add_argument(
        "--memory-gb",
        type=float,
        default=6.0,
        help="cap on the sweep's data memory (RLIMIT_DATA) [GiB]: a case asking for more ends "
        "in a MemoryError, counted as unbounded (0: no cap)",
    )
    parser.add_argument("--verbose", action="store_true", help="one line per case as it ends")
    parser.add_argument(
        "--match", default=None, help="run only the cases whose name holds this text"
    )
    parser.add_argument(
        "--subprocess",
        action="store_true",
        help="one interpreter per case, as a shell runs it (slower: pydrake imports each time); "
        "default: every case in this process through pcvfe_drake.cli.main",
    )
    args = parser.parse_args()
    selected = [c for c in cases() + more_cases() if args.only in (None, c.category)]
    if args.match is not None:
        selected = [c for c in selected if args.match in c.name]
    if args.quick:
        seen = collections.Counter()
        selected = [c for c in selected if (seen.update([c.category]) or seen[c.category] <= 2)]
    if args.memory_gb > 0:  # a case that asks for unbounded memory fails, not the machine
        import resource

        limit = int(args.memory_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))
    work = Path(tempfile.mkdtemp(prefix="pcvfe_sweep_")) if args.keep is None else args.keep
    work.mkdir(parents=True, exist_ok=True)
    needed = {c.damage[0] for c in selected if c.damage is not None}
    if any("{log}" in a for c in selected for a in c.args):
        needed.add("log")
    makers = {"run": make_run, "results": make_results, "bag": make_bag, "log": make_log}
    for old in ("run", "results", "bag", "log"):  # fixtures of an earlier sweep in --keep
        for path in work.glob(f"fixture_{old}*"):
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    fixtures = {name: makers[name](work) for name in sorted(needed)}
    t_start = time.perf_counter()
    rows = []
    for c in selected:
        rows.append(run_case(c, work, fixtures, args.timeout, not args.subprocess))
        if args.verbose:
            r = rows[-1]
            print(f"{r['outcome']:>9} {r['seconds']:6.1f} s  {r['category']} / {r['case']}")
    by_category = collections.defaultdict(list)
    for r in rows:
        by_category[r["category"]].append(r)
    totals = collections.Counter()
    header = f"{'category':<40} {'cases':>5} " + " ".join(f"{o:>9}" for o in OUTCOMES) + "  exits"
    print(header)
    for category, items in by_category.items():
        counts = collections.Counter(r["outcome"] for r in items)
        totals.update(counts)
        exits = collections.Counter(str(r["exit"]) for r in items)
        print(
            f"{category:<40} {len(items):>5} "
            + " ".join(f"{counts[o]:>9}" for o in OUTCOMES)
            + "  "
            + ", ".join(f"{k}:{v}" for k, v in sorted(exits.items()))
        )
    print(f"{'all':<40} {len(rows):>5} " + " ".join(f"{totals[o]:>9}" for o in OUTCOMES))
    for r in rows:
        if r["outcome"] not in ("named", "degraded"):
            print(
                f"  {r['outcome']}: {r['category']} / {r['case']} (exit {r['exit']}): "
                f"{r['why'] or r['stderr_last_line']}"
            )
    if args.keep is None:
        _writable_again(work)
        shutil.rmtree(work, ignore_errors=True)
    passed = totals["named"] + totals["degraded"] == len(rows)
    target = (
        "every case a named error or the documented degraded behaviour: 0 tracebacks, "
        "0 hangs or unbounded runs, 0 silently wrong, 0 data lost"
    )
    print(f"wall time {time.perf_counter() - t_start:.0f} s for the cases")
    print(
        json.dumps(
            {
                "target": target,
                "passed": passed,
                "cases": len(rows),
                **{o: totals[o] for o in OUTCOMES},
                "rows": rows,
            }
        )
    )
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
