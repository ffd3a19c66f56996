"""The drive-log table format: measured or simulated drives as CSV or Parquet.

A drive log is a table with one row per sample (documented in ``docs/drive_log.md``):

=============  =========  ==========================================================
column         unit       meaning
=============  =========  ==========================================================
``t``          s          time, strictly increasing
``sx``, ``sy`` m          position of the centre of gravity in the world frame
``delta``      rad        front wheel steering angle
``v``          m/s        speed of the centre of gravity
``psi``        rad        heading (yaw); wrapped or unwrapped
``psi_dot``    rad/s      yaw rate
``beta``       rad        side-slip angle at the centre of gravity
``steer_rate`` rad/s      commanded steering rate (input held from this row to the next)
``accel``      m/s^2      commanded longitudinal acceleration (held likewise)
=============  =========  ==========================================================

Optional columns: ``terrain`` (str, the terrain name; empty = unknown), ``context`` (int, a
context/cluster id; -1 = noise), ``mu_true`` (friction coefficient, > 0; empty/NaN = unknown,
as on a real car), ``image`` (str, path of
a camera image; relative paths are relative to the log file's folder). Extra columns are allowed
and kept.

Loading validates the table and reports every problem in one :class:`DriveLogError`: missing
columns, non-numeric values, NaN/inf values (with row numbers), non-increasing time, time gaps,
and values whose range or mutual consistency shows a wrong unit (degrees instead of radians, km/h
instead of m/s). Row numbers are 0-based data rows (in a CSV file, row ``i`` is on line ``i + 2``).

:class:`DriveLogWriter` appends rows to a CSV file chunk by chunk and flushes each chunk, so a run
that is interrupted keeps every row written so far.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO

import numpy as np
import pandas as pd

from pcvfe_drake.runs.drivelog_physics import (
    consistency_checks,
    single_sample_checks,
    span_steps,
)

REQUIRED_COLUMNS: tuple[str, ...] = (
    "t",
    "sx",
    "sy",
    "delta",
    "v",
    "psi",
    "psi_dot",
    "beta",
    "steer_rate",
    "accel",
)
"""Columns every drive log has, in this order."""

COLUMN_UNITS: dict[str, str] = {
    "t": "s",
    "sx": "m",
    "sy": "m",
    "delta": "rad",
    "v": "m/s",
    "psi": "rad",
    "psi_dot": "rad/s",
    "beta": "rad",
    "steer_rate": "rad/s",
    "accel": "m/s^2",
    "mu_true": "-",
}

OPTIONAL_COLUMNS: tuple[str, ...] = ("terrain", "context", "mu_true", "image")
"""Optional columns with a defined meaning (see the module docstring)."""
TRUE_STATE_COLUMNS: tuple[str, ...] = (
    "true_sx",
    "true_sy",
    "true_delta",
    "true_v",
    "true_psi",
    "true_psi_dot",
    "true_beta",
)
"""Sim-only columns of a simulated run's true state (its state columns are then the measured
state); not validated, ignored by fits."""

# Plausible magnitudes; beyond them the unit is almost certainly wrong (see docs/drive_log.md).
MAX_ABS_DELTA_RAD = 1.6
"""Largest plausible steering angle (~92 deg); a larger value suggests degrees."""
MAX_ABS_BETA_RAD = math.pi / 2
"""Largest plausible side-slip angle (90 deg); a larger value suggests degrees."""
MAX_ABS_PSI_DOT_RADPS = 6.0
"""Largest plausible yaw rate (~344 deg/s); a larger value suggests deg/s."""
MAX_ABS_STEER_RATE_RADPS = 7.0
"""Largest plausible steering rate (~400 deg/s); a larger value suggests deg/s."""
MAX_ABS_V_MPS = 100.0
"""Largest plausible speed (360 km/h); a larger value suggests km/h or mph."""
MAX_ABS_ACCEL_MPS2 = 50.0
"""Largest plausible longitudinal acceleration (~5 g)."""
MAX_MU_TRUE = 3.0
"""Largest plausible friction coefficient."""
GAP_FACTOR = 5.0
"""A time step larger than this many times the median step is a gap (unless ``max_gap_s``)."""
MAX_LISTED_ROWS = 10
"""How many row numbers an error message lists per problem before summarising."""

_MIN_MOTION_ROWS = 10
SAME_QUANTITY_TOL = 0.1
"""``v`` and the speed from sx, sy over t are the same quantity, and so are ``psi_dot`` and the
rate of ``psi``: their median ratio must be within 1 +- this (a scale error of a few percent, e.g.
a tire radius, passes; 10 % already moves the fitted mu by ~0.2)."""
_LOG_NAME = re.compile(r"\.(csv|csv\.gz|parquet|pq)$")


class DriveLogError(ValueError):
    """A drive log that does not follow the format; ``problems`` lists every finding."""

    def __init__(self, source: str, problems: list[str]) -> None:
        self.source = source
        self.problems = list(problems)
        lines = "\n".join(f"  - {p}" for p in self.problems)
        super().__init__(f"drive log {source}: {len(self.problems)} problem(s):\n{lines}")


def _rows(index: Iterable[int]) -> str:
    idx = [int(i) for i in index]
    shown = ", ".join(str(i) for i in idx[:MAX_LISTED_ROWS])
    if len(idx) > MAX_LISTED_ROWS:
        shown += f", ... ({len(idx)} rows in all)"
    return f"row{'s' if len(idx) != 1 else ''} {shown}"


def _numeric_column(
    df: pd.DataFrame, name: str, problems: list[str], *, missing_ok: bool = False
) -> np.ndarray | None:
    """The column as float (NaN where missing/inf, reported unless ``missing_ok`` for missing),
    or None if it is not numeric."""
    raw = df[name]
    if pd.api.types.is_numeric_dtype(raw.dtype):
        # Numbers already (every chunk a run writes): nothing to coerce, nothing non-numeric.
        arr = raw.to_numpy(dtype=float, copy=True)
    else:
        values = pd.to_numeric(raw, errors="coerce")
        not_numeric = values.isna() & raw.notna()
        if not_numeric.any():
            rows = np.flatnonzero(not_numeric.to_numpy())
            examples = ", ".join(repr(raw.iloc[i]) for i in rows[:3])
            problems.append(
                f"column '{name}': non-numeric values at {_rows(rows)} (e.g. {examples})"
            )
            return None
        arr = values.to_numpy(dtype=float, copy=True)
    nan_rows = np.flatnonzero(np.isnan(arr))
    if nan_rows.size and not missing_ok:
        problems.append(f"column '{name}': NaN/missing at {_rows(nan_rows)}")
    inf_rows = np.flatnonzero(np.isinf(arr))
    if inf_rows.size:
        problems.append(f"column '{name}': infinite at {_rows(inf_rows)}")
    arr[inf_rows] = np.nan  # reported once here; NaN rows are skipped by the later checks
    return arr


def _check_range(name: str, arr: np.ndarray | None, limit: float, hint: str, problems: list[str]):
    if arr is None:
        return
    bad = np.flatnonzero(np.abs(arr) > limit)
    if bad.size:
        worst = float(arr[bad[np.argmax(np.abs(arr[bad]))]])
        unit = COLUMN_UNITS.get(name, "")
        problems.append(
            f"column '{name}': |value| > {limit:g} {unit} at {_rows(bad)} (largest {worst:g}); "
            f"{hint}"
        )


def _time_checks(t: np.ndarray, max_gap_s: float | None, problems: list[str]) -> None:
    if t.size < 2:
        return
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0) + 1
    if bad.size:
        problems.append(
            f"column 't': time does not increase at {_rows(bad)} "
            f"(t[i] <= t[i-1], e.g. row {bad[0]}: {t[bad[0] - 1]:g} -> {t[bad[0]]:g} s)"
        )
    positive = dt[dt > 0]
    if positive.size == 0:
        return
    median_dt = float(np.median(positive))
    limit = GAP_FACTOR * median_dt if max_gap_s is None else float(max_gap_s)
    gaps = np.flatnonzero(dt > limit) + 1
    if gaps.size:
        largest = float(dt.max())
        how = (
            f"{GAP_FACTOR:g} x the median step {median_dt:g} s"
            if max_gap_s is None
            else f"max_gap_s={limit:g} s"
        )
        problems.append(
            f"column 't': time gaps longer than {how} before {_rows(gaps)} (largest {largest:g} s)"
        )


def _speed_consistency(cols: dict[str, np.ndarray | None], problems: list[str]) -> None:
    """Compare ``v`` with the speed implied by the positions: a ratio of 3.6 means km/h, etc."""
    t, sx, sy, v = (cols.get(k) for k in ("t", "sx", "sy", "v"))
    if any(a is None for a in (t, sx, sy, v)) or t.size < _MIN_MOTION_ROWS:
        return
    # Over ~0.2 s: position noise would inflate the distance of single steps.
    k = min(span_steps(t), t.size - 1)
    dt = t[k:] - t[:-k]
    ok = dt > 0
    if ok.sum() < _MIN_MOTION_ROWS:
        return
    with np.errstate(invalid="ignore"):
        path_speed = np.hypot(sx[k:] - sx[:-k], sy[k:] - sy[:-k])[ok] / dt[ok]
        v_mid = 0.5 * np.abs(v[k:] + v[:-k])[ok]
        moving = (path_speed > 0.5) & (v_mid > 0.5)
    if moving.sum() < _MIN_MOTION_ROWS:
        return
    ratio = float(np.median(v_mid[moving] / path_speed[moving]))
    if abs(ratio - 1.0) <= SAME_QUANTITY_TOL:
        return
    hints = (
        (3.6, "v in km/h?"),
        (2.237, "v in mph?"),
        (1000.0, "t in ms?"),
        (0.001, "sx/sy in mm?"),
    )
    hint = "check the units of v, sx, sy and t (v is the speed of the centre of gravity)"
    for factor, text in hints:
        if abs(math.log(ratio / factor)) < 0.15:
            hint = text
            break
    problems.append(
        f"column 'v': v is {ratio:.3g} times the speed implied by sx, sy over t "
        f"(expected ~1); {hint}"
    )


def _yaw_consistency(cols: dict[str, np.ndarray | None], problems: list[str]) -> None:
    """Compare the change of ``psi`` with ``psi_dot``: a ratio of ~57 means psi in degrees."""
    t, psi, r = (cols.get(k) for k in ("t", "psi", "psi_dot"))
    if any(a is None for a in (t, psi, r)) or t.size < _MIN_MOTION_ROWS:
        return
    # Over ~0.2 s (heading noise would dominate single steps): the change of psi against the
    # integral of psi_dot (trapezoid). Spans across a wrap (+-2 pi, or +-360 in degrees) are rare
    # outliers; the median ignores them.
    k = min(span_steps(t), t.size - 1)
    steps = np.diff(t)
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * steps)])
    dt = t[k:] - t[:-k]
    dpsi = psi[k:] - psi[:-k]
    turned = integral[k:] - integral[:-k]
    with np.errstate(invalid="ignore"):
        turning = (dt > 0) & (np.abs(turned) > 0.05 * dt) & np.isfinite(dpsi)
    if turning.sum() < _MIN_MOTION_ROWS:
        return
    ratio = float(np.median(dpsi[turning] / turned[turning]))
    if abs(ratio - 1.0) <= SAME_QUANTITY_TOL:
        return
    if abs(math.log(abs(ratio) / 57.2958)) < 0.2:
        hint = "psi in degrees?"
    elif abs(math.log(abs(ratio) * 57.2958)) < 0.2:
        hint = "psi_dot in deg/s?"
    elif ratio < 0:
        hint = "opposite sign conventions of psi and psi_dot?"
    else:
        hint = "check the units of psi, psi_dot and t"
    problems.append(
        f"column 'psi': psi changes {ratio:.3g} times as fast as psi_dot says (expected ~1); {hint}"
    )


def validate_drive_log(
    df: pd.DataFrame,
    source: str = "<DataFrame>",
    max_gap_s: float | None = None,
    check_units: bool = True,
) -> pd.DataFrame:
    """Check ``df`` against the drive-log format; raise one :class:`DriveLogError` listing all.

    Args:
        df: the table.
        source: a name for messages (usually the file path).
        max_gap_s: the largest allowed time step [s]; default ``GAP_FACTOR`` x the median step.
            ``math.inf`` disables the gap check.
        check_units: run the range and consistency checks that catch wrong units (off for
            the chunks of :class:`DriveLogWriter`, so a simulated spin is never refused).
    Returns:
        ``df`` itself, unchanged, when it is valid.
    """
    if not isinstance(df, pd.DataFrame):
        raise DriveLogError(source, [f"expected a pandas DataFrame, got {type(df).__name__}"])
    problems: list[str] = []
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        problems.append(
            f"missing column(s) {missing} (required: {', '.join(REQUIRED_COLUMNS)}; "
            f"found: {', '.join(map(str, df.columns))})"
        )
    duplicated = sorted({str(c) for c in df.columns[df.columns.duplicated()]})
    if duplicated:
        problems.append(f"duplicated column name(s) {duplicated}")
        raise DriveLogError(source, problems)
    if len(df) == 0:
        problems.append("no rows")
        raise DriveLogError(source, problems)

    cols: dict[str, np.ndarray | None] = {}
    for name in (*REQUIRED_COLUMNS, "mu_true"):
        if name in df.columns:
            # mu_true may be missing (empty/NaN) where the truth is unknown: a real car's log
            # or a hardware run.
            cols[name] = _numeric_column(df, name, problems, missing_ok=name == "mu_true")

    if cols.get("t") is not None:
        _time_checks(cols["t"], max_gap_s, problems)
    if check_units:
        _unit_checks(cols, problems)
    _optional_checks(df, cols, problems)
    if problems:
        raise DriveLogError(source, problems)
    return df


def _unit_checks(cols: dict[str, np.ndarray | None], problems: list[str]) -> None:
    first = len(problems)
    _check_range("delta", cols.get("delta"), MAX_ABS_DELTA_RAD, "degrees instead of rad?", problems)
    _check_range("beta", cols.get("beta"), MAX_ABS_BETA_RAD, "degrees instead of rad?", problems)
    _check_range(
        "psi_dot", cols.get("psi_dot"), MAX_ABS_PSI_DOT_RADPS, "deg/s instead of rad/s?", problems
    )
    _check_range(
        "steer_rate",
        cols.get("steer_rate"),
        MAX_ABS_STEER_RATE_RADPS,
        "deg/s instead of rad/s?",
        problems,
    )
    _check_range("v", cols.get("v"), MAX_ABS_V_MPS, "km/h or mph instead of m/s?", problems)
    _check_range("accel", cols.get("accel"), MAX_ABS_ACCEL_MPS2, "wrong unit?", problems)
    _speed_consistency(cols, problems)
    _yaw_consistency(cols, problems)
    # Columns already found in a wrong unit are left out of the physics checks (one cause, one
    # message).
    flagged = set(re.findall(r"column '([a-z_]+)'", " ".join(problems[first:])))
    physics = {k: (None if k in flagged else a) for k, a in cols.items()}
    single_sample_checks(physics, problems, _rows, MAX_ABS_STEER_RATE_RADPS)
    consistency_checks(physics, problems)


def _optional_checks(
    df: pd.DataFrame, cols: dict[str, np.ndarray | None], problems: list[str]
) -> None:
    mu = cols.get("mu_true")
    if mu is not None:
        bad = np.flatnonzero(~np.isnan(mu) & ((mu <= 0) | (mu > MAX_MU_TRUE)))
        if bad.size:
            problems.append(
                f"column 'mu_true': values outside (0, {MAX_MU_TRUE:g}] at {_rows(bad)} "
                f"(e.g. {mu[bad[0]]:g})"
            )
    if "context" in df.columns:
        ctx = pd.to_numeric(df["context"], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(ctx) | (ctx != np.round(ctx)) | (ctx < -1))
        if bad.size:
            problems.append(
                f"column 'context': not an integer >= -1 at {_rows(bad)} "
                f"(e.g. {df['context'].iloc[bad[0]]!r})"
            )
    for name in ("terrain", "image"):
        if name in df.columns:
            col = df[name]
            bad = np.flatnonzero(~col.map(lambda s: isinstance(s, str) or pd.isna(s)).to_numpy())
            if bad.size:
                problems.append(
                    f"column '{name}': not text at {_rows(bad)} (e.g. {col.iloc[bad[0]]!r})"
                )


def _format_of(path: Path) -> str:
    name = path.name.lower()
    if name.endswith((".csv", ".csv.gz")):
        return "csv"
    if name.endswith((".parquet", ".pq")):
        return "parquet"
    raise ValueError(f"drive log {path}: unknown file type (use .csv, .csv.gz, .parquet or .pq)")


def _normalise(df: pd.DataFrame) -> pd.DataFrame:
    """Float numeric columns, int contexts, text terrain/image (missing text -> ''); converts the
    columns of ``df`` in place (the reader's own table: no copy of a long log)."""
    out = df
    for name in (*REQUIRED_COLUMNS, "mu_true"):
        if name in out.columns:
            out[name] = pd.to_numeric(out[name]).astype(float)
    if "context" in out.columns:
        out["context"] = pd.to_numeric(out["context"]).astype(np.int64)
    for name in ("terrain", "image"):
        if name in out.columns:
            out[name] = out[name].map(lambda s: "" if pd.isna(s) else str(s)).astype(object)
    return out


def _undecodable_rows(values: list[bytes | None]) -> tuple[np.ndarray, list[bytes]]:
    """Rows whose bytes are not UTF-8, and up to 3 examples."""
    rows, examples = [], []
    for i, raw in enumerate(values):
        if raw is None:
            continue
        try:
            raw.decode("utf-8")
        except UnicodeDecodeError:
            rows.append(i)
            if len(examples) < 3:
                examples.append(raw[:40])
    return np.asarray(rows, dtype=np.int64), examples


def _read_parquet(path: Path) -> tuple[pd.DataFrame, list[str]]:
    """A Parquet file as a DataFrame, and a problem per text column holding invalid UTF-8.

    Such a column (Parquet strings must be UTF-8, but writers do not all check) is decoded with
    the bad bytes replaced by U+FFFD, so that the caller can choose to reject or go on.
    (Dictionary-encoded text is checked by pyarrow while reading: a read error.)
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    problems = []
    for k, name in enumerate(table.column_names):
        column = table.column(k)
        if not (pa.types.is_string(column.type) or pa.types.is_large_string(column.type)):
            continue
        try:
            column.validate(full=True)
            continue
        except pa.ArrowInvalid:
            pass
        raw = column.cast(pa.large_binary()).to_pylist()
        rows, examples = _undecodable_rows(raw)
        problems.append(
            f"column '{name}': text that is not valid UTF-8 at {_rows(rows)} "
            f"(e.g. {', '.join(map(repr, examples))}); re-write the file with UTF-8 text "
            "(`pcvfe fit --lenient`, i.e. validate=False, reads it with U+FFFD for the bad bytes)"
        )
        text = [None if b is None else b.decode("utf-8", "replace") for b in raw]
        table = table.set_column(k, name, pa.array(text, type=pa.large_string()))
    # self_destruct frees each Arrow column once converted: a long log is not held twice.
    return table.to_pandas(self_destruct=True, split_blocks=True), problems


def read_drive_log(
    path: str | os.PathLike,
    validate: bool = True,
    max_gap_s: float | None = None,
    check_units: bool = True,
) -> pd.DataFrame:
    """Load a drive log from CSV or Parquet (by suffix), validated and with normalised dtypes.

    ``max_gap_s`` and ``check_units`` are passed to :func:`validate_drive_log`.

    Raises:
        FileNotFoundError: no such file.
        DriveLogError: the file is unreadable or breaks the format (every problem listed).
    """
    path = Path(path)
    if path.is_dir():
        inside = sorted(
            q.name for q in path.iterdir() if q.is_file() and _LOG_NAME.search(q.name.lower())
        )
        found = f"; it holds {', '.join(inside[:5])}: name one of them" if inside else ""
        raise ValueError(f"drive log {path} is a folder, not a file{found}")
    if not path.is_file():
        raise FileNotFoundError(f"drive log {path}: no such file")
    fmt = _format_of(path)
    encoding: list[str] = []
    try:
        if fmt == "csv":
            df = pd.read_csv(path, dtype={"terrain": str, "image": str}, keep_default_na=True)
        else:
            df, encoding = _read_parquet(path)
    except Exception as exc:  # parser errors of pandas/pyarrow come in many types
        raise DriveLogError(str(path), [f"cannot be read as {fmt}: {exc}"]) from exc
    if validate:
        try:
            validate_drive_log(df, source=str(path), max_gap_s=max_gap_s, check_units=check_units)
        except DriveLogError as exc:
            raise DriveLogError(str(path), encoding + exc.problems) from None
        if encoding:
            raise DriveLogError(str(path), encoding)
        df = _normalise(df)
    return df


def write_drive_log(
    df: pd.DataFrame,
    path: str | os.PathLike,
    validate: bool = True,
    max_gap_s: float | None = None,
) -> Path:
    """Write a drive log as CSV or Parquet (by suffix), required columns first; returns the path."""
    path = Path(path)
    fmt = _format_of(path)
    if validate:
        validate_drive_log(df, source=str(path), max_gap_s=max_gap_s)
    ordered = [c for c in REQUIRED_COLUMNS if c in df.columns]
    ordered += [c for c in df.columns if c not in REQUIRED_COLUMNS]
    out = df[ordered]
    path.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "csv":
        out.to_csv(path, index=False)
    else:
        out.to_parquet(path, index=False)
    return path


class DriveLogWriter:
    """Appends rows to a CSV drive log as a run goes, flushing every chunk to disk.

    The first chunk fixes the columns (required ones first, then the others in their order);
    later chunks must have the same set of columns. Each chunk is checked on its own (columns,
    numbers, NaN/inf, time order; not the unit heuristics, so a simulated spin is never refused)
    and time must keep increasing across chunks. An interrupted run leaves a readable CSV with
    every row appended so far. (Parquet files are only readable once closed, so this writer
    writes CSV; convert at the end with ``write_drive_log(read_drive_log(p), p_parquet)``.)

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, path: str | os.PathLike, overwrite: bool = True) -> None:
        self.path = Path(path)
        if _format_of(self.path) != "csv" or self.path.name.lower().endswith(".gz"):
            raise ValueError(
                f"DriveLogWriter: {self.path}: incremental logs are plain .csv files "
                "(Parquet and gzip are unreadable until closed)"
            )
        if self.path.exists() and not overwrite:
            raise FileExistsError(f"DriveLogWriter: {self.path} exists (overwrite=False)")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[str] | None = open(self.path, "w", newline="")  # noqa: SIM115
        self._columns: list[str] | None = None
        self._last_t = -math.inf
        self._write_failed = False
        self.rows_written = 0

    def append(self, rows: pd.DataFrame | Mapping[str, Iterable] | Iterable[Mapping]) -> None:
        """Append a chunk: a DataFrame, a dict of columns, or a list of row dicts."""
        if self._file is None:
            raise ValueError(f"DriveLogWriter: {self.path} is closed")
        chunk = rows if isinstance(rows, pd.DataFrame) else pd.DataFrame(rows)
        if len(chunk) == 0:
            return
        source = f"{self.path} (chunk from row {self.rows_written})"
        if self._columns is None:
            columns = [c for c in REQUIRED_COLUMNS if c in chunk.columns]
            columns += [c for c in chunk.columns if c not in REQUIRED_COLUMNS]
        else:
            columns = self._columns
            if set(chunk.columns) != set(columns):
                raise DriveLogError(
                    source,
                    [
                        f"columns {sorted(map(str, chunk.columns))} differ from the log's "
                        f"{sorted(columns)}"
                    ],
                )
        validate_drive_log(chunk, source=source, max_gap_s=math.inf, check_units=False)
        t0 = float(chunk["t"].iloc[0])
        if not t0 > self._last_t:
            raise DriveLogError(
                source, [f"column 't': chunk starts at {t0:g} s, not after {self._last_t:g} s"]
            )
        try:
            chunk[columns].to_csv(self._file, header=self._columns is None, index=False)
            self._file.flush()
        except OSError as exc:  # e.g. a full disk: name the file (rows written so far are kept)
            self._write_failed = True
            raise OSError(exc.errno, exc.strerror, str(self.path)) from exc
        self._columns = columns
        self._last_t = float(chunk["t"].iloc[-1])
        self.rows_written += len(chunk)

    def close(self) -> None:
        if self._file is not None:
            file, self._file = self._file, None
            try:
                file.close()  # flushes; the file is closed even when that fails
            except OSError as exc:
                if not self._write_failed:  # a failed append has already reported it
                    raise OSError(exc.errno, exc.strerror, str(self.path)) from exc

    def __enter__(self) -> DriveLogWriter:
        return self

    def __exit__(self, exc_type, *exc_info) -> None:
        try:
            self.close()
        except OSError:
            if exc_type is None:  # else the error that ended the block is the one to report
                raise
