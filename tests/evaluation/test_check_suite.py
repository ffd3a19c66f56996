"""``make bench`` / ``make validate``'s runner on tiny scripts: results, errors and verdicts."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from pcvfe_drake.evaluation.suite import discover, last_json, run_suite

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "validation"))
from run_all import verdict  # noqa: E402

sys.path.pop(0)


def _script(folder: Path, name: str, body: str) -> None:
    (folder / f"{name}.py").write_text("import json, sys\n" + body + "\n")


def test_suite_collects_last_json_and_flags_errors_and_failures(tmp_path, capsys):
    folder = tmp_path / "checks"
    folder.mkdir()
    _script(folder, "good", 'print("working"); print(json.dumps({"target": "t", "passed": True}))')
    _script(folder, "bad", 'print(json.dumps({"target": "t", "passed": False}))')
    _script(folder, "prose", 'print("no json here")')
    _script(folder, "quick", 'print(json.dumps({"quick": "--quick" in sys.argv, "passed": True}))')
    _script(folder, "_helper", "raise SystemExit(3)")
    (folder / "run_all.py").write_text("raise SystemExit(4)\n")
    assert [p.stem for p in discover(folder)] == ["bad", "good", "prose", "quick"]
    out = tmp_path / "results.json"
    code = run_suite(
        folder,
        quick=True,
        only=None,
        timeout_s=60.0,
        out=out,
        headline=verdict,
        failed=lambda r: verdict(r).startswith("FAIL"),
    )
    results = json.loads(out.read_text())
    assert code == 1
    assert results["good"] == {"target": "t", "passed": True}
    assert results["quick"]["quick"] is True
    assert "no JSON object" in results["prose"]["error"]
    table = capsys.readouterr().out
    assert "[good] working" in table and "PASS: t" in table and "FAIL: t" in table
    code = run_suite(
        folder,
        quick=False,
        only=["good"],
        timeout_s=60.0,
        out=out,
        headline=verdict,
        failed=lambda r: verdict(r).startswith("FAIL"),
    )
    assert code == 0


def test_unknown_script_is_named(tmp_path):
    with pytest.raises(SystemExit, match="nope"):
        discover(tmp_path, ["nope"])


def test_verdicts():
    assert verdict({"target": "x", "passed": True}).startswith("PASS")
    assert verdict({"target": "x"}).startswith("FAIL")  # no verdict is no pass
    assert verdict({"skipped": True, "reason": "no chromium"}).startswith("SKIPPED")
    with pytest.raises(ValueError, match="not an object"):
        last_json(["[1, 2]"])
