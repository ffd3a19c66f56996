"""The run log of a closed-loop simulation: drive-log rows written to disk as the run goes.

A :class:`RunLog` receives one sample at a time (from the ``RunLogger`` LeafSystem's periodic
publish), keeps every row in memory for the summary, and appends chunks of ``chunk_rows`` rows to
a CSV drive log through :class:`pcvfe_drake.runs.drivelog.DriveLogWriter`, which flushes each chunk:
a run interrupted at any point keeps everything up to its last chunk (call :meth:`close` to
write the rest).

Columns: the drive-log columns (``t``, the ST state, the inputs), then ``terrain`` (true terrain
name; sim-only), ``terrain_index``, ``mu_true`` (sim-only), ``context`` (reported context id, -1 =
noise), ``mu_hat``, ``C_Sf_hat``, ``C_Sr_hat`` (the estimate the controller was given),
``true_sx`` ... ``true_beta`` (sim-only true state; the state columns are the measured state), the
features ``f_00``... and ``image`` (path of a saved camera frame relative to the log's folder,
empty on rows without one; a frame is saved every ``frame_period_s``).

Beside the rows, :meth:`RunLog.add_sample` keeps the state and the input at the fitter's
sampling rate (what the fitter read), written at :meth:`RunLog.close` to ``SAMPLES_FILE``
(compressed, beside the drive log): with the drive log's features of every camera frame, what
``pcvfe replay`` needs to rerun the estimator exactly at any log rate.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from pcvfe_drake.runs.drivelog import TRUE_STATE_COLUMNS, DriveLogError, DriveLogWriter
from pcvfe_drake.runs.output_paths import os_error_text
from pcvfe_drake.vehicle.single_track import INPUT_NAMES, NX, STATE_NAMES

ESTIMATE_COLUMNS = ("mu_hat", "C_Sf_hat", "C_Sr_hat")
SAMPLES_FILE = "fitter_samples.npz"
"""The state and input at the fitter's sampling rate (arrays ``t_s``, ``state``, ``actuation``)."""


class RunLogWriteError(OSError):
    """The drive log (or a camera frame) could not be written; the message names the path and
    the reason. The rows stay in memory (the summary still sees them); nothing more is written
    to disk."""


def feature_columns(n: int) -> list[str]:
    """Names of the feature columns: f_00, f_01, ..."""
    return [f"f_{i:02d}" for i in range(n)]


class RunLog:
    """Rows of one run, in memory and appended to ``path`` (a .csv drive log) chunk by chunk.

    Args:
        path: the CSV drive log to write (its folder also receives ``frames/``); None keeps the
            rows in memory only.
        terrain_names: names of the terrain map's terrains, by index (for the ``terrain`` column).
        feature_dim: length of the feature vector.
        chunk_rows: rows per appended chunk (at 10 Hz, 50 rows: a killed process
            loses at most 5 s of the run; Ctrl-C loses nothing).
        frame_period_s: save a camera frame (PNG) every this many seconds; 0 saves none.
    """

    def __init__(
        self,
        path: str | Path | None,
        terrain_names: list[str],
        feature_dim: int,
        *,
        chunk_rows: int = 50,
        frame_period_s: float = 2.0,
    ) -> None:
        if chunk_rows < 1:
            raise ValueError(f"RunLog: chunk_rows={chunk_rows!r} must be >= 1")
        self.path = Path(path) if path is not None else None
        self.terrain_names = list(terrain_names)
        self.columns = [
            "t",
            *STATE_NAMES,
            *INPUT_NAMES,
            "terrain",
            "terrain_index",
            "mu_true",
            "context",
            *ESTIMATE_COLUMNS,
            *TRUE_STATE_COLUMNS,
            *feature_columns(feature_dim),
            "image",
        ]
        self.feature_dim = int(feature_dim)
        self.chunk_rows = int(chunk_rows)
        self.frame_period_s = float(frame_period_s)
        self._rows: list[list] = []
        self._pending: list[list] = []
        self._next_frame_t = 0.0
        self.errors: list[str] = []
        self.write_error: str | None = None
        """Why the log stopped being written to disk (``"path: reason"``), or None."""
        self._writer = DriveLogWriter(self.path) if self.path is not None else None
        self._samples: list[list[float]] = []
        self.frame_dir = self.path.parent / "frames" if self.path is not None else None

    def __len__(self) -> int:
        return len(self._rows)

    def wants_frame(self, t_s: float) -> bool:
        """True when a camera frame should be saved with the sample at ``t_s``."""
        return self.frame_dir is not None and self.frame_period_s > 0 and t_s >= self._next_frame_t

    def append(
        self,
        t_s: float,
        state: np.ndarray,
        actuation: np.ndarray,
        features: np.ndarray,
        context_id: float,
        theta_hat: np.ndarray,
        mu_true: float,
        terrain_index: float,
        image_rgb: np.ndarray | None = None,
        true_state: np.ndarray | None = None,
    ) -> None:
        """Add one sample (``image_rgb``: an (H, W, 3) uint8 frame to save, or None;
        ``true_state``: the sim-only true state (7), None where the station has none: NaN)."""
        state = np.asarray(state, dtype=float).reshape(NX)
        actuation = np.asarray(actuation, dtype=float).reshape(len(INPUT_NAMES))
        features = np.asarray(features, dtype=float).reshape(-1)
        if features.size != self.feature_dim:
            raise ValueError(
                f"RunLog: features has {features.size} entries, not {self.feature_dim}"
            )
        k = int(round(float(terrain_index)))
        terrain = self.terrain_names[k] if 0 <= k < len(self.terrain_names) else ""
        image = ""
        if image_rgb is not None and self.write_error is None and self.wants_frame(t_s):
            name = f"frame_{int(round(t_s * 1000)):08d}.png"
            bgr = cv2.cvtColor(np.ascontiguousarray(image_rgb[..., :3]), cv2.COLOR_RGB2BGR)
            try:
                self.frame_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:  # no frames; the log itself goes on
                self.errors.append(f"no camera frames: {os_error_text(exc, self.frame_dir)}")
                self.frame_period_s = 0.0
            else:
                if cv2.imwrite(str(self.frame_dir / name), bgr):
                    image = f"frames/{name}"
            self._next_frame_t = t_s + self.frame_period_s - 1e-9
        row = [
            float(t_s),
            *state.tolist(),
            *actuation.tolist(),
            terrain,
            k,
            float(mu_true),
            int(round(float(context_id))),
            *np.asarray(theta_hat, dtype=float).reshape(3).tolist(),
            *(np.full(NX, np.nan) if true_state is None else np.asarray(true_state, float))
            .reshape(NX)
            .tolist(),
            *features.tolist(),
            image,
        ]
        self._rows.append(row)
        self._pending.append(row)
        if len(self._pending) >= self.chunk_rows:
            self.flush()

    def add_sample(self, t_s: float, state: np.ndarray, actuation: np.ndarray) -> None:
        """Keep the state (7) and the input (2) read at ``t_s`` at the fitter's sampling rate."""
        # Python floats (tolist), not numpy scalars: cheaper to build and to keep, same values.
        self._samples.append(
            [float(t_s), *np.asarray(state, float).tolist(), *np.asarray(actuation, float).tolist()]
        )

    def write_samples(self) -> None:
        """Write the samples to :data:`SAMPLES_FILE` beside the drive log (none: nothing);
        an OS error is noted in ``write_error`` (the drive log stays valid without it)."""
        if self.path is None or not self._samples or self.write_error is not None:
            return
        values = np.asarray(self._samples, dtype=float)
        path = self.path.parent / SAMPLES_FILE
        try:
            np.savez_compressed(
                path, t_s=values[:, 0], state=values[:, 1 : 1 + NX], actuation=values[:, 1 + NX :]
            )
        except OSError as exc:
            self.write_error = f"cannot write {os_error_text(exc, path)}"

    def flush(self) -> None:
        """Append the pending rows to the CSV file now. A chunk the drive-log format rejects
        (e.g. a non-finite state) is kept in memory and its error noted in ``errors``."""
        if not self._pending or self._writer is None:
            self._pending = []
            return
        chunk = pd.DataFrame(self._pending, columns=self.columns)
        self._pending = []
        try:
            self._writer.append(chunk)
        except DriveLogError as exc:
            self.errors.append(str(exc))
        except OSError as exc:
            self._fail(exc, self.path)

    def _fail(self, exc: OSError, path: Path) -> None:
        """Stop writing to disk after an OS error (a full disk) and raise RunLogWriteError."""

        self.write_error = f"cannot write {os_error_text(exc, path)}"
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.close()
            except OSError:
                pass  # the same error again: the rows are kept in memory
        raise RunLogWriteError(exc.errno, self.write_error) from exc

    def close(self) -> None:
        """Write the pending rows and close the file, then the samples (idempotent)."""
        try:
            self.flush()
        except RunLogWriteError:
            return  # noted in write_error
        self.write_samples()
        self._samples = []
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.close()
            except OSError as exc:
                self.write_error = f"cannot write {os_error_text(exc, self.path)}"

    def rows_since(self, start: int) -> list[list]:
        """The rows logged from row index ``start`` on (for progress reports)."""
        return self._rows[start:]

    def to_frame(self) -> pd.DataFrame:
        """All rows logged so far as a DataFrame."""
        df = pd.DataFrame(self._rows, columns=self.columns)
        return df.astype({"terrain_index": int, "context": int})
