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
"""

from __future__ import annotations

import numpy as np
import pandas as pd

STATE_COLUMNS = ("sx", "sy", "delta", "v", "psi", "psi_dot", "beta")
INPUT_COLUMNS = ("steer_rate", "accel")


def resample_log(
    df: pd.DataFrame, rate_hz: float, source: str = "<log>", max_gap_s: float | None = None
) -> pd.DataFrame:
    """The log on a uniform grid of ``rate_hz`` (see the module docstring for the rule).

    Raises:
        ValueError: for a rate that is not a positive number, a log without an increasing
            time column ``t``, or a gap longer than ``max_gap_s``.
    """
    try:
        rate = float(rate_hz)
    except (TypeError, ValueError):
        rate = float("nan")
    if not np.isfinite(rate) or rate <= 0:
        raise ValueError(f"--resample {rate_hz!r}: the rate must be a positive number of Hz")
    if "t" not in df.columns:
        raise ValueError(f"drive log {source}: no column 't' to resample on")
    t = pd.to_numeric(df["t"], errors="coerce").to_numpy(dtype=float)
    if t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError(
            f"drive log {source}: column 't' must be finite and strictly increasing to "
            "resample (sort the log and drop duplicate time stamps first)"
        )
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
