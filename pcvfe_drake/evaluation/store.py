"""The results folder of ``pcvfe evaluate``: tables written run by run, and resume (no pydrake).

Layout of ``--out DIR``::

    experiment.yaml      the experiment as run (every field), rewritten at each call
    environment.json     package versions of the client, command line, start time
    runs.parquet         one row per run (status, error, timings, metrics)
    laps.parquet         one row per lap of every run
    contexts.parquet     one row per discovered context of every run
    failures.parquet     one row per catastrophic failure (time, place, kind)
    runs/<run_id>/       summary.json, drive_log.parquet, scenario.yaml; error.txt if it failed
    report.md, report.html, figures/   the report (``pcvfe evaluate --report DIR``)

Each finished run is written at once: its folder first, then the four tables (each rewritten to
a temporary file and renamed over the old one, so a crash never leaves a torn table). A run is
done when ``runs.parquet`` has it with status ``done`` and the same ``spec_hash`` (the hash of
its complete scenario): a second call with the same folder skips those and reruns failed ones
and any whose experiment changed.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from pcvfe_drake.evaluation.tables import run_row

TABLES = ("runs", "laps", "contexts", "failures")
"""The tables of a results folder (``<name>.parquet``)."""


TABLE_COLUMNS = {
    "runs": ("run_id", "scenario", "source", "seed", "spec_hash", "status", "error"),
    "laps": ("run_id", "source", "seed"),
    "contexts": ("run_id", "source", "seed"),
    "failures": ("run_id", "source", "seed"),
}
"""Columns each table has whatever the runs did (the report reads them)."""


class ResultsFolderError(ValueError):
    """A file of a results folder cannot be read or is not what the folder writes; the
    message names the file."""


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _read_table(path: Path) -> pd.DataFrame:
    """A Parquet table of the folder; a ``ResultsFolderError`` naming it when unreadable or
    (a results table) without its columns."""
    try:
        table = pd.read_parquet(path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several kinds for a damaged file
        raise ResultsFolderError(
            f"{path}: not a readable Parquet table ({_one_line(exc)})"
        ) from exc
    required = () if path.name == "drive_log.parquet" else TABLE_COLUMNS.get(path.stem, ())
    missing = [c for c in required if c not in table.columns] if len(table.columns) else []
    if missing:
        raise ResultsFolderError(
            f"{path}: not a results table of pcvfe evaluate (no column(s) {', '.join(missing)})"
        )
    return table


def _write_atomic(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    write(tmp)
    os.replace(tmp, path)


class ResultStore:
    """Reads and writes a results folder (see the module docstring)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.runs_dir = self.root / "runs"
        self.figures = self.root / "figures"
        self._tables: dict[str, pd.DataFrame] | None = None

    def table_path(self, name: str) -> Path:
        return self.root / f"{name}.parquet"

    def run_dir(self, run_id: str) -> Path:
        return self.runs_dir / run_id

    # ------------------------------------------------------------------ reading
    def exists(self) -> bool:
        return self.table_path("runs").is_file()

    def table(self, name: str) -> pd.DataFrame:
        """A stored table (empty DataFrame when absent). A table that cannot be read, or that
        lacks a column every row of it has (:data:`TABLE_COLUMNS`), is a ``ResultsFolderError``
        naming the file."""
        if self._tables is None:
            tables = {}
            for n in TABLES:
                p = self.table_path(n)
                tables[n] = _read_table(p) if p.is_file() else pd.DataFrame()
            self._tables = tables
        return self._tables[name]

    def done(self) -> dict[str, str]:
        """``{run_id: spec_hash}`` of the runs stored as done."""
        runs = self.table("runs")
        if runs.empty:
            return {}
        ok = runs[runs["status"] == "done"]
        return dict(zip(ok["run_id"], ok["spec_hash"], strict=True))

    def pending(self, specs: Iterable) -> list:
        """The specs not yet done (a done run whose scenario changed is pending again)."""
        done = self.done()
        return [s for s in specs if done.get(s.run_id) != s.spec_hash]

    def drive_log(self, run_id: str) -> pd.DataFrame | None:
        """A run's drive log (None when absent); unreadable: ``ResultsFolderError``."""
        p = self.run_dir(run_id) / "drive_log.parquet"
        return _read_table(p) if p.is_file() else None

    def experiment_dict(self) -> dict:
        """The experiment as run ({} when absent); not a YAML mapping: ``ResultsFolderError``."""
        p = self.root / "experiment.yaml"
        if not p.is_file():
            return {}
        try:
            data = yaml.safe_load(p.read_text())
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise ResultsFolderError(f"{p}: not valid YAML ({_one_line(exc)})") from exc
        if not isinstance(data, dict):
            raise ResultsFolderError(f"{p}: not an experiment (a YAML mapping of fields)")
        return data

    def environment(self) -> dict:
        """The client's environment ({} when absent); not a JSON object: ``ResultsFolderError``."""
        p = self.root / "environment.json"
        if not p.is_file():
            return {}
        try:
            data = json.loads(p.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ResultsFolderError(f"{p}: not valid JSON ({_one_line(exc)})") from exc
        if not isinstance(data, dict):
            raise ResultsFolderError(f"{p}: not a JSON object")
        return data

    # ------------------------------------------------------------------ writing
    def start(self, experiment: Mapping[str, Any], environment: Mapping[str, Any]) -> None:
        """Create the folder; write the experiment as run and the client's environment."""
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        (self.root / "experiment.yaml").write_text(
            yaml.safe_dump(dict(experiment), sort_keys=False)
        )
        (self.root / "environment.json").write_text(json.dumps(dict(environment), indent=2))

    def record(self, spec: Mapping[str, Any], result: Mapping[str, Any]) -> dict[str, Any]:
        """Store one run's result (its folder, then every table); returns its runs-table row."""
        run_id = spec["run_id"]
        folder = self.run_dir(run_id)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "scenario.yaml").write_text(yaml.safe_dump(spec["scenario"], sort_keys=False))
        if result.get("summary"):
            (folder / "summary.json").write_text(
                json.dumps(result["summary"], indent=2, allow_nan=False)
            )
        if result.get("drive_log_parquet"):
            _write_atomic(
                folder / "drive_log.parquet", lambda p: p.write_bytes(result["drive_log_parquet"])
            )
        error_file = folder / "error.txt"
        if result.get("status") == "failed":
            error_file.write_text(f"{result.get('error', '')}\n\n{result.get('traceback', '')}")
        elif error_file.exists():
            error_file.unlink()
        row = run_row(spec, result)
        ident = {"run_id": run_id, "source": spec["source"], "seed": int(spec["seed"])}
        ident["scenario"] = spec["scenario_name"]
        new = {
            "runs": [row],
            "laps": [{**ident, **r} for r in result.get("laps") or []],
            "contexts": [{**ident, **r} for r in result.get("contexts") or []],
            "failures": [{**ident, **r} for r in result.get("failures") or []],
        }
        for name in TABLES:
            old = self.table(name)
            if not old.empty:
                old = old[old["run_id"] != run_id]
            rows = pd.DataFrame(new[name])
            frames = [f for f in (old, rows) if not f.empty]
            table = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
            if name != "runs" and table.empty:
                table = pd.DataFrame(columns=["run_id", "source", "seed", "scenario"])
            self._tables[name] = table
            _write_atomic(self.table_path(name), lambda p, t=table: t.to_parquet(p, index=False))
        return row
