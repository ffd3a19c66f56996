"""The scripts of ``benchmarks/`` and ``validation/`` run under their ``run_all.py``; studies
import only the package.

``run_all`` (``make bench``, ``make validate``) runs each script with no argument or with
``--quick`` only; a script that lacks the option, or requires an argument, fails there. A
validation script states its target and its verdict (``target``, ``passed``) in the JSON it
prints last. A study is frozen and may be run on its own: it must not reach into another
folder through ``sys.path``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted(
    p
    for folder in ("benchmarks", "validation")
    for p in (ROOT / folder).glob("*.py")
    if p.name != "run_all.py" and not p.name.startswith("_")
)
VALIDATION = [p for p in SCRIPTS if p.parent.name == "validation"]
STUDIES = sorted((ROOT / "studies").glob("*/*.py"))


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


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_script_takes_quick_and_requires_nothing(path):
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


@pytest.mark.parametrize("path", VALIDATION, ids=lambda p: p.stem)
def test_validation_states_target_and_verdict(path):
    text = path.read_text()
    assert '"target"' in text and '"passed"' in text, f"{path.name}: no target / passed in JSON"


def test_the_homes_are_sorted():
    assert len(SCRIPTS) > 20 and len(VALIDATION) >= 7 and len(STUDIES) >= 8
    for folder in ("benchmarks", "validation"):
        assert (ROOT / folder / "run_all.py").is_file()


@pytest.mark.parametrize("path", STUDIES, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_study_imports_only_the_package(path):
    assert "sys.path" not in path.read_text(), f"{path}: sys.path manipulation"
    assert (path.parent / "README.md").is_file(), f"{path.parent}: no README.md"
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            top = node.module.split(".")[0]
            assert top not in ("benchmarks", "validation", "studies", "_own_run"), (
                f"{path.name}: imports {node.module}"
            )
