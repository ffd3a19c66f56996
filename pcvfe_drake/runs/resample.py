"""Resample a drive log onto a uniform time grid (for jittered or uneven logger timestamps).

Rule (stated in ``docs/drive_log.md`` and the ``--resample`` help):

* the new grid runs from the first time stamp in steps of ``1 / rate_hz`` up to the last one;
* measured states (sx, sy, delta, v, psi, psi_dot, beta) are interpolated linearly; the
  heading is unwrapped first and wrapped back to (-pi, pi] after;
* the inputs (steer_rate, accel) are commands held from one row to the next (zero-order
  hold); each new step gets their *average* over that step, so the integral of the steering
  rate (the steering angle) is kept exactly at the new sample times;
* every other column (contexts, labels, image references) is taken from the nearest row.

A grid point that falls in a gap longer than ``max_gap_s`` (default: 5 x the median step) is
refused with the rows named: resampling must not invent data across a hole in the log.

Bounds (checked before any work, :func:`check_resample_rate` and :func:`check_resampled_rows`):
the rate is at most :data:`MAX_RESAMPLE_HZ` and the resampled log at most
:data:`MAX_RESAMPLED_ROWS` rows; the refusal gives the rows and the memory the request implies.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

STATE_COLUMNS = ("sx", "sy", "delta", "v", "psi", "psi_dot", "beta")
INPUT_COLUMNS = ("steer_rate", "accel")

MAX_RESAMPLE_HZ = 1000.0
"""Highest resampling rate [Hz]: a car's sensors give at most ~1 kHz (IMUs), so a finer grid
only interpolates between the same measurements while the fit's work grows with every row."""
MAX_RESAMPLED_ROWS = 2_000_000
"""Most rows a resampled log may have (33 min at 1 kHz): the fit and the diagnosis keep several
arrays per row, on the order of a kilobyte per row in all (:data:`BYTES_PER_ROW_FIT`)."""
BYTES_PER_ROW_FIT = 1000
"""Rough memory per row of a fit or a diagnosis [bytes], for the estimate in a refusal."""


def _size_text(rows: float) -> str:
    """``"N rows (~X GB)"`` for a resampled log of ``rows`` rows."""
    gb = rows * BYTES_PER_ROW_FIT / 1e9
    return f"{rows:.3g} rows (~{gb:.3g} GB for the fit)"


def check_resample_rate(rate_hz, option: str = "--resample") -> float:
    """``rate_hz`` as a float when it is a positive rate within :data:`MAX_RESAMPLE_HZ`; else a
    ValueError naming ``option`` (call it before loading the log: it needs no data)."""
    try:
        rate = float(rate_hz)
    except (TypeError, ValueError):
        rate = float("nan")
    if not np.isfinite(rate) or rate <= 0:
        raise ValueError(f"{option} {rate_hz!r}: the rate must be a positive number of Hz")
    if rate > MAX_RESAMPLE_HZ:
        raise ValueError(
            f"{option} {rate_hz!r}: at most {MAX_RESAMPLE_HZ:g} Hz (a car's sensors give no "
            f"more; each minute of log would be {_size_text(60.0 * rate)})"
        )
    return rate


def check_resampled_rows(duration_s: float, rate_hz: float, source: str = "<log>") -> int:
    """Rows of ``duration_s`` of log resampled at ``rate_hz``; a ValueError naming ``source``
    and the estimate when that exceeds :data:`MAX_RESAMPLED_ROWS`."""
    rows = float(np.floor(duration_s * rate_hz + 1e-9)) + 1.0
    if rows > MAX_RESAMPLED_ROWS:
        raise ValueError(
            f"drive log {source}: {duration_s:.6g} s at --resample {rate_hz:g} Hz would be "
            f"{_size_text(rows)}, more than the {MAX_RESAMPLED_ROWS} rows allowed: "
            "resample at a lower rate or split the log"
        )
    return int(rows)


def resample_log(
    df: pd.DataFrame, rate_hz: float, source: str = "<log>", max_gap_s: float | None = None
) -> pd.DataFrame:
    """The log on a uniform grid of ``rate_hz`` (see the module docstring for the rule).

    Raises:
        ValueError: for a rate that is not a positive number or beyond the bounds (module
            docstring), a log without an increasing time column ``t``, or a gap longer than
            ``max_gap_s``.
    """
    rate = check_resample_rate(rate_hz)
    if "t" not in df.columns:
        raise ValueError(f"drive log {source}: no column 't' to resample on")
    t = pd.to_numeric(df["t"], errors="coerce").to_numpy(dtype=float)
    if t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError(
            f"drive log {source}: column 't' must be finite and strictly increasing to "
            "resample (sort the log and drop duplicate time stamps first)"
        )
    check_resampled_rows(float(t[-1] - t[0]), rate, source)
    steps = np.diff(t)
    gap = 5.0 * float(np.median(steps)) if max_gap_s is None else float(max_gap_s)
    dt = 1.0 / rate
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1)
    after = np.clip(np.searchsorted(t, grid, side="left"), 1, t.size - 1)
    span = t[after] - t[after - 1]
    bad = span > gap
    if np.any(bad):
        i = int(after[np.argmax(bad)])
        raise ValueError(
            f"drive log {source}: a gap of {span[np.argmax(bad)]:.3g} s between rows {i} and "
            f"{i + 1} (t = {t[i - 1]:.6g} .. {t[i]:.6g} s) is longer than {gap:.3g} s; "
            "resampling would invent data there: split the log at the gap"
        )
    out = {"t": grid}
    held = np.clip(np.searchsorted(t, grid + 1e-9 * dt, side="right") - 1, 0, t.size - 1)
    nearest = np.clip(np.rint(np.interp(grid, t, np.arange(t.size))).astype(int), 0, t.size - 1)
    for col in df.columns:
        if col == "t":
            continue
        if col in STATE_COLUMNS:
            y = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
            if col == "psi":
                y = np.unwrap(y)
                y = np.interp(grid, t, y)
                out[col] = np.pi - np.mod(np.pi - y, 2.0 * np.pi)
            else:
                out[col] = np.interp(grid, t, y)
        elif col in INPUT_COLUMNS:
            u = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
            # integral of the held input at the original times, then at the grid points
            cum = np.concatenate([[0.0], np.cumsum(u[:-1] * steps)])
            k = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, t.size - 1)
            at = cum[k] + u[k] * (grid - t[k])
            avg = np.empty(grid.size)
            avg[:-1] = np.diff(at) / dt
            avg[-1] = u[held[-1]]
            out[col] = avg
        else:
            out[col] = df[col].to_numpy()[nearest]
    return pd.DataFrame(out, columns=list(df.columns))
