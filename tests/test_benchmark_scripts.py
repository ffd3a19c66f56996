"""Every benchmark runs under ``benchmarks/run_all.py``: it takes ``--quick`` and needs no argument.

``run_all`` (``make bench``) runs each ``benchmarks/<name>.py`` with no argument or with
``--quick`` only; a script that lacks the option, or requires an argument, fails there.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

BENCHMARKS = sorted(
    p
    for p in (Path(__file__).resolve().parents[1] / "benchmarks").glob("*.py")
    if p.name != "run_all.py" and not p.name.startswith("_")
)


def _options(path: Path) -> list[ast.Call]:
    calls = []
    for node in ast.walk(ast.parse(path.read_text())):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "add_argument"
        ):
            calls.append(node)
    return calls


@pytest.mark.parametrize("path", BENCHMARKS, ids=lambda p: p.stem)
def test_benchmark_takes_quick_and_requires_nothing(path):
    calls = _options(path)
    names = [a.value for c in calls for a in c.args if isinstance(a, ast.Constant)]
    assert "--quick" in names, f"{path.name}: no --quick option (run_all --quick passes it)"
    for call in calls:
        flag = [a.value for a in call.args if isinstance(a, ast.Constant)]
        nargs = [k.value.value for k in call.keywords if k.arg == "nargs"]
        optional = all(str(f).startswith("-") for f in flag) or nargs in (["*"], ["?"])
        assert optional, f"{path.name}: positional {flag} is required"
        for kw in call.keywords:
            required = isinstance(kw.value, ast.Constant) and kw.value.value is True
            assert not (kw.arg == "required" and required), f"{path.name}: {flag} is required"
