"""The run folder of ``pcvfe simulate``: preparing it and writing what a run leaves (no pydrake).

The simulation loop (``pcvfe_drake.diagrams.run_simulation``) drives the diagram; everything that
touches the disk after it lives here, so it can be tested without Drake and so every OS error
has one place where it becomes a message naming the path and the reason:

- :meth:`RunFolder.prepare` checks the path (``pcvfe_drake.runs.output_paths.check_output_dir``:
  a file, a file among the parents, no permission), creates the folder, refuses one that
  already holds a run unless ``overwrite`` (then it removes the old run's files, and only
  those: :data:`RUN_FILES` and :data:`RUN_DIRS`); its errors are ``ValueError`` subclasses
  naming the path and the reason, which the CLI prints as one line.
- :func:`write_run_outputs` writes ``playback.html``, the figures and ``summary.json`` (last, so
  it can list what was written); a write that fails (a full disk) is noted in
  ``summary["write_errors"]`` as ``"path: reason"`` and the other files are still written.

A run folder holds::

    drive_log.csv    the drive log, appended as the run goes (pcvfe_drake.runs.runlog)
    fitter_samples.npz  state and input at the fitter's sampling rate (for pcvfe replay)
    frames/          camera frames referenced by the log's image column
    scenario.yaml    the scenario as run (every field, so the run can be repeated)
    summary.json     pcvfe_drake.runs.summary.summarize_run plus run facts (below)
    playback.html    the Meshcat recording (with a Meshcat)
    figures/         the paper's Fig. 4, 5, 7 (pcvfe_drake.runs.figures)
    internal_error.txt  only after a failure of the scoring or the figures (a bug): tracebacks
"""

from __future__ import annotations

import json
import os
import re
import shutil
import traceback
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pcvfe_drake.json_numbers import finite_or_none
from pcvfe_drake.runs.figures import write_figures
from pcvfe_drake.runs.output_paths import check_output_dir, describe_os_error, os_error_text
from pcvfe_drake.runs.runlog import SAMPLES_FILE
from pcvfe_drake.runs.summary import summarize_run

INTERNAL_ERROR_FILE = "internal_error.txt"
"""Tracebacks of failures of the project's own code while the outputs were written."""
RUN_FILES = (
    "drive_log.csv",
    SAMPLES_FILE,
    "summary.json",
    "playback.html",
    "scenario.yaml",
    INTERNAL_ERROR_FILE,
)
"""Files a run writes into its folder."""
RUN_DIRS = ("figures", "frames")
"""Folders a run writes into its folder."""


DEFAULT_RUNS_DIR = Path("runs")
"""Where ``pcvfe simulate`` puts a run without ``--out`` (relative to the working directory)."""
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
MAX_NAME_CHARS = 80
"""Longest folder-name part taken from a scenario name (file systems allow 255 bytes)."""


def run_folder_name(tag: str, when: datetime) -> str:
    """The default run folder's name for ``tag`` (the scenario's name, and its estimator): one
    path component whatever the name holds (separators, ``..``, newlines and other characters
    outside ``A-Z a-z 0-9 . _ -`` become ``_``, dots and ``_`` at the ends are dropped), so the
    folder stays in :data:`DEFAULT_RUNS_DIR`; then the time."""
    safe = _UNSAFE.sub("_", tag)[:MAX_NAME_CHARS].strip("._") or "run"
    return f"{safe}-{when:%Y%m%d-%H%M%S}"


class RunFolderError(ValueError):
    """The run folder cannot be used or written; the message names the path and the reason."""


class RunFolder:
    """File names of a run folder, and its preparation (see the module docstring)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.drive_log = self.root / "drive_log.csv"
        self.summary = self.root / "summary.json"
        self.playback = self.root / "playback.html"
        self.figures = self.root / "figures"
        self.frames = self.root / "frames"
        self.scenario = self.root / "scenario.yaml"
        self.internal_error = self.root / INTERNAL_ERROR_FILE

    def run_entries(self) -> list[Path]:
        """The entries of a previous run in the folder (files of :data:`RUN_FILES`, folders of
        :data:`RUN_DIRS`)."""
        if not self.root.is_dir():
            return []
        names = [*RUN_FILES, *RUN_DIRS]
        return [self.root / n for n in names if os.path.lexists(self.root / n)]

    def prepare(self, *, overwrite: bool = False) -> list[str]:
        """Create the folder for a new run; returns the names of an old run's entries removed
        (``overwrite``). Raises :class:`RunFolderError` naming the path and the reason when the
        folder cannot be created or written, or already holds a run and ``overwrite`` is False.
        """
        root = self.root
        check_output_dir(root, "--out")  # a file, a file among the parents, no permission
        try:
            root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RunFolderError(
                f"cannot create the run folder {os_error_text(exc, root)}"
            ) from exc
        old = self.run_entries()
        if old and not overwrite:
            raise RunFolderError(
                f"{root}: already holds a run ({', '.join(p.name for p in old)}); give another "
                "folder, or --overwrite to replace that run (removes those entries only)"
            )
        removed = []
        for entry in old:
            try:
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
            except OSError as exc:
                raise RunFolderError(
                    f"cannot remove the previous run's {os_error_text(exc, entry)}"
                ) from exc
            removed.append(entry.name)
        probe = root / ".pcvfe-write-test"
        try:
            probe.write_text("")
            probe.unlink()
        except OSError as exc:
            raise RunFolderError(
                f"cannot write into the run folder {os_error_text(exc, root)}"
            ) from exc
        return removed

    def write_text(self, path: Path, text: str) -> None:
        """Write ``text`` to ``path`` (in the folder); raise :class:`RunFolderError` naming the
        path and the reason on an OS error (a partly written file is removed)."""
        try:
            path.write_text(text)
        except OSError as exc:
            try:
                path.unlink(missing_ok=True)
            except OSError:
                pass
            raise RunFolderError(f"cannot write {os_error_text(exc, path)}") from exc


@dataclass
class SimulationResult:
    """What a run returns: the summary (as written to ``summary.json``), the figures written
    (name: path, None when not drawable, with the reason in ``figure_notes``), the playback
    page, drive-log chunks the format rejected, and files that could not be written."""

    summary: dict[str, Any]
    figures: dict[str, str | None] = field(default_factory=dict)
    figure_notes: dict[str, str] = field(default_factory=dict)
    playback: Path | None = None
    log_errors: list[str] = field(default_factory=list)
    write_errors: list[str] = field(default_factory=list)
    held_signals: list[str] = field(default_factory=list)
    """Ctrl-C / SIGTERM received while the outputs were written (held back until they were)."""
    log: Any = None
    """The run log as a pandas DataFrame (drive-log columns, ``final_context`` included)."""
    internal_errors: list = field(default_factory=list)
    """:class:`InternalError` of each failure of the scoring or the figures (a bug)."""


@dataclass
class RunRecord:
    """What the simulation loop hands to the writer (all plain data)."""

    scenario: Any
    """The ``pcvfe_drake.runs.scenario.Scenario`` that ran."""
    log: pd.DataFrame
    """The run log (``RunLog.to_frame()``) with the ``final_context`` column."""
    course: Any
    terrain_map: Any
    estimate_table: list[dict]
    wall_time_s: float
    cpu_time_s: float
    nmpc_updates: int
    nmpc_fallbacks: int
    interrupted: bool = False
    interrupt_signal: str | None = None
    error: str | None = None
    ending_failure: dict | None = None
    """The failure that ended the run where no logged state shows it (``FailureEvent.to_dict()``
    of a ``truth_singular`` event: the truth could not be integrated further), else None."""
    stop_reason: str = "duration"
    """``"duration"``, ``"laps"``, ``"max_duration"``, ``"failure"``, ``"interrupted"`` or
    ``"error"``."""
    log_errors: list[str] = field(default_factory=list)
    write_errors: list[str] = field(default_factory=list)
    """Files the loop could not write (the drive log on a full disk), ``"path: reason"``."""
    station_status: dict | None = None
    """The station's ``station_status`` at the end (``StationStatus.to_dict()``)."""
    rows_skipped_state_not_finite: int = 0
    """Rows the run logger skipped because the station's state was not finite."""


def build_summary(record: RunRecord) -> dict[str, Any]:
    """``summary.json``'s content: :func:`summarize_run` plus the run's facts."""
    scenario = record.scenario
    summary = summarize_run(
        record.log,
        scenario=scenario.name,
        wall_time_s=record.wall_time_s,
        terrain_mu={t.name: t.mu for t in record.terrain_map.terrains},
        excluded_terrains=record.terrain_map.transitions,
        course=record.course,
        estimate_table=record.estimate_table,
        interrupted=record.interrupted,
        ending_failure=record.ending_failure,
    )
    summary.update(run_facts(record, summary["sim_time_s"]))
    return summary


def unscored_summary(record: RunRecord) -> dict[str, Any]:
    """What ``summary.json`` holds when scoring failed: the facts that need no scoring (rows,
    time span, how the run ended, the fitter's final table) and none of the scores."""
    t = record.log["t"].to_numpy(float) if "t" in record.log.columns else np.array([])
    t = t[np.isfinite(t)]
    sim_time = float(t[-1] - t[0]) if t.size else 0.0
    summary: dict[str, Any] = {
        "scenario": record.scenario.name,
        "interrupted": bool(record.interrupted),
        "sim_time_s": sim_time,
        "wall_time_s": float(record.wall_time_s),
        "log_rows": len(record.log),
        "scored": False,
        "estimate_table": record.estimate_table,
    }
    summary.update(run_facts(record, sim_time))
    return summary


def run_facts(record: RunRecord, sim_time_s: float) -> dict[str, Any]:
    """The run's facts beside the scores (settings, how it ended, the station, the NMPC)."""
    scenario = record.scenario
    summary: dict[str, Any] = {}
    cpu = record.cpu_time_s
    summary["cpu_time_s"] = cpu
    summary["realtime_factor_cpu"] = sim_time_s / cpu if cpu > 0 else None
    summary["truth_model"] = scenario.truth_model
    summary["feature_backend"] = scenario.features.backend
    summary["seed"] = scenario.seed
    summary["estimator"] = scenario.estimator
    summary["friction_mapping"] = scenario.friction_mapping
    summary["sensing"] = scenario.sensing.model
    summary["unknown_context"] = type(scenario.fitter.handing.unknown).__name__
    summary["stop_reason"] = record.stop_reason
    if record.interrupt_signal is not None:
        summary["interrupt_signal"] = record.interrupt_signal
    if record.error is not None:
        summary["error"] = record.error
    if record.station_status is not None:
        summary["station_status"] = record.station_status
    summary["rows_skipped_state_not_finite"] = int(record.rows_skipped_state_not_finite)
    summary["nmpc_fallbacks"] = int(record.nmpc_fallbacks)
    summary["nmpc_updates"] = int(record.nmpc_updates)
    return summary


def json_ready(value: Any) -> Any:
    """``value`` with NaN and infinities as None, numpy scalars as Python numbers (what
    ``json.dumps(..., allow_nan=False)`` accepts), in nested dicts, lists and tuples."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return finite_or_none(value)
    return value


@dataclass
class InternalError:
    """A failure of the project's own code while the outputs were written (a bug, not the
    user's input): the stage (``"summary"``, ``"figures"``), the exception and its traceback."""

    stage: str
    message: str
    traceback: str

    def to_dict(self, traceback_file: str | None) -> dict[str, Any]:
        out: dict[str, Any] = {"stage": self.stage, "message": self.message}
        if traceback_file is not None:
            out["traceback_file"] = traceback_file
        else:
            out["traceback"] = self.traceback
        return out


def _internal_error(stage: str, exc: BaseException) -> InternalError:
    return InternalError(
        stage=stage,
        message=f"{type(exc).__name__}: {exc}",
        traceback="".join(traceback.format_exception(exc)),
    )


def write_run_outputs(
    record: RunRecord,
    folder: RunFolder | None,
    *,
    playback_html: str | None = None,
    reference_xy: np.ndarray | None = None,
) -> SimulationResult:
    """Summarize ``record`` and write playback, figures and ``summary.json`` into ``folder``
    (None: summarize only). Never raises for an OS error: each failed write is reported in
    ``summary["write_errors"]`` (and the result's ``write_errors``) and the rest is written.

    A failure of the scoring or of the figures (any other exception: a bug of this project,
    whatever the run did) does not lose the run either: ``summary.json`` is written with what
    could be computed (:func:`unscored_summary` when the scores failed) and
    ``summary["internal_errors"]`` lists each failure; its traceback goes to
    :data:`INTERNAL_ERROR_FILE` in the folder (the result's ``internal_errors`` too, for the
    command to report)."""
    internal: list[InternalError] = []
    try:
        summary = build_summary(record)
    except Exception as exc:  # noqa: BLE001 - any bug in scoring must not lose the run
        internal.append(_internal_error("summary", exc))
        summary = unscored_summary(record)
    result = SimulationResult(
        summary=summary,
        log_errors=list(record.log_errors),
        write_errors=list(record.write_errors),
        log=record.log,
    )
    if folder is not None:
        _write_files(record, folder, result, internal, playback_html, reference_xy)
    result.internal_errors = internal
    if internal:
        tb_file = None
        if folder is not None:
            text = "\n".join(f"[{e.stage}]\n{e.traceback}" for e in internal)
            try:
                folder.write_text(folder.internal_error, text)
                tb_file = folder.internal_error.name
            except RunFolderError as exc:
                result.write_errors.append(str(exc))
        summary["internal_errors"] = [e.to_dict(tb_file) for e in internal]
    if result.write_errors:
        summary["write_errors"] = list(result.write_errors)
    if folder is not None:
        try:
            text = json.dumps(json_ready(summary), indent=2, allow_nan=False)
            folder.write_text(folder.summary, text)
        except RunFolderError as exc:
            result.write_errors.append(str(exc))
    return result


def _write_files(
    record: RunRecord,
    folder: RunFolder,
    result: SimulationResult,
    internal: list[InternalError],
    playback_html: str | None,
    reference_xy: np.ndarray | None,
) -> None:
    """Playback and figures into ``folder``; ``result.summary["files"]`` lists what exists."""
    summary = result.summary
    if playback_html is not None:
        try:
            folder.write_text(folder.playback, playback_html)
            result.playback = folder.playback
        except RunFolderError as exc:
            result.write_errors.append(str(exc))
    terrain_map = record.terrain_map
    x0, x1, y0, y1 = terrain_map.bounds_m
    if not internal:  # the figures draw from the scores
        try:
            from pcvfe_drake.perception.ground_render import render_topdown

            map_image = render_topdown(terrain_map, px_per_m=2.0)
            result.figures = write_figures(
                record.log,
                folder.figures,
                summary,
                map_image=map_image,
                map_bounds_m=(x0, x1, y0, y1),
                reference_xy=reference_xy,
                log_dir=folder.root,
            )
        except OSError as exc:
            result.write_errors.append(
                f"cannot write the figures: {os_error_text(exc, folder.figures)}"
            )
        except Exception as exc:  # noqa: BLE001 - a bug in a figure must not lose the summary
            internal.append(_internal_error("figures", exc))
    if result.figures.get("fig7_reidentification", "") is None:
        result.figure_notes["fig7_reidentification"] = "no re-identification in this run"
    summary["files"] = {
        "drive_log": folder.drive_log.name if folder.drive_log.exists() else None,
        "playback": folder.playback.name if result.playback else None,
        "figures": {
            k: (Path(v).relative_to(folder.root).as_posix() if v else None)
            for k, v in result.figures.items()
        },
    }


def internal_error_report(result: SimulationResult, folder: RunFolder | None) -> str:
    """The lines a command prints (to stderr) for the result's internal errors: what failed,
    where its traceback is, and what was still written."""
    if not result.internal_errors:
        return ""
    lines = []
    for e in result.internal_errors:
        lines.append(f"internal error while writing the {e.stage} (a bug, not your input): "
                     f"{e.message}")  # fmt: skip
    if folder is None:
        lines.append(result.internal_errors[0].traceback.rstrip())
        return "\n".join(lines)
    written = [
        p.name
        for p in (folder.drive_log, folder.scenario, folder.playback, folder.summary)
        if p.exists()
    ]
    written += [f"figures/{Path(v).name}" for v in result.figures.values() if v]
    scored = result.summary.get("scored", True)
    lines.append(
        f"  still written in {folder.root}: {', '.join(written) or 'nothing'}"
        + ("" if scored else " (summary.json without scores)")
    )
    if folder.internal_error.exists():
        lines.append(f"  traceback: {folder.internal_error}")
    return "\n".join(lines)
