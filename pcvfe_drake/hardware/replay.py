"""A recorded drive as a time-indexed source: what the replay station plays (no pydrake).

:class:`ReplayLog` holds a drive log (``t``, the ST state, the inputs, optional ``mu_true``,
``terrain_index``/``terrain`` and camera frames) and answers, for any time ``t``:

- ``state_at(t)``: the state of the newest row at or before ``t`` (zero-order hold);
- ``actuation_before(t)``: the input applied just before ``t`` (the row's input is held from that
  row to the next, so this is the input of the newest row strictly before ``t``; zero before
  the first row, as a controller's output before its first update);
- ``frame_at(t)``: the index of the newest camera frame captured before ``t``.

Frame capture times: a frame saved by ``pcvfe simulate`` with the row at time r was taken at the
newest camera tick strictly before r (the run logger reads the camera just before the camera's
update at r; at r = 0 the initial frame), so :meth:`from_run_folder` maps frames back to their
capture times with the run's camera period. A drive log imported from a bag
(``pcvfe import-bag``) has one row per frame at its capture time (``frame_times="row"``).

A run folder holds more than the rows: the features of every camera frame (the drive log's
``f_00``... columns, each row holding those of the frame taken before it) and the state and
input at the fitter's sampling rate (``fitter_samples.npz``). With them a replay feeds the
clustering and the fitter what they had in the run (``features_at``, and ``state_at`` /
``actuation_before`` from the samples), whatever the log and frame rates.
"""

from __future__ import annotations

import math
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.runs.drivelog import TRUE_STATE_COLUMNS, read_drive_log
from pcvfe_drake.runs.runlog import SAMPLES_FILE
from pcvfe_drake.vehicle.single_track import INPUT_NAMES, STATE_NAMES

_EPS_S = 1e-9


@dataclass
class ReplayLog:
    """A drive as arrays: ``t_s`` (N,), ``states`` (N, 7), ``actuations`` (N, 2), optional
    ``mu_true`` (N,) and ``terrain_index`` (N,) (None: no truth), and frames (capture times
    ``frame_t_s`` (M,), absolute ``frame_paths``)."""

    t_s: np.ndarray
    states: np.ndarray
    actuations: np.ndarray
    frame_t_s: np.ndarray
    frame_paths: list[Path]
    mu_true: np.ndarray | None = None
    terrain_index: np.ndarray | None = None
    source: str = ""
    true_states: np.ndarray | None = None
    """(N, 7) the simulated run's true state (``true_*`` columns; None: the log has none)."""
    feature_t_s: np.ndarray | None = None
    """(K,) capture times of the camera frames whose features the log holds (None: none)."""
    features: np.ndarray | None = None
    """(K, D) the features computed in the run from those frames (the ``f_00``... columns):
    a replay feeds them to the clustering as they were, so it needs no saved image."""
    sample_t_s: np.ndarray | None = None
    """(S,) times of the state and input kept at the fitter's sampling rate (a run folder's
    ``fitter_samples.npz``; None: none), used for ``state_at`` and ``actuation_before``."""
    sample_states: np.ndarray | None = None
    sample_actuations: np.ndarray | None = None

    def __post_init__(self) -> None:
        if len(self.t_s) == 0:
            raise ValueError(f"replay {self.source}: the drive log has no rows")
        if np.any(np.diff(self.t_s) <= 0):
            raise ValueError(f"replay {self.source}: times are not increasing")

    @property
    def duration_s(self) -> float:
        """Time of the last row [s]."""
        return float(self.t_s[-1])

    @property
    def has_truth(self) -> bool:
        return self.mu_true is not None

    def fidelity(self, sample_period_s: float, camera_period_s: float) -> dict:
        """What a replay of this log can reproduce, for a fitter sampling every
        ``sample_period_s`` and a camera every ``camera_period_s``: ``{"exact": bool,
        "log_period_s", "frame_period_s", "frames", "camera_frames", "reasons": [...]}``.

        A replay feeds the estimator the logged rows and frames. It equals the original run
        (where that run was deterministic) only when every fitter sample has its row (rows at
        least as often as the fitter samples) and every camera frame was saved; otherwise the
        fitter sees each row's state held until the next row (a 20 Hz log: five samples per
        row, four of them stale), and the clustering sees a frame only where one was saved (the
        frames in between are blank: features NaN, context noise), so contexts and estimates
        differ.
        """
        dt = np.diff(self.sample_t_s if self.sample_t_s is not None else self.t_s)
        log_period = float(np.median(dt)) if len(dt) else math.nan
        reasons = []
        if not (log_period <= sample_period_s * (1 + 1e-6)):
            reasons.append(
                f"rows every {log_period:g} s, the fitter samples every {sample_period_s:g} s: "
                f"it sees each row's state held for {log_period / sample_period_s:.0f} samples"
            )
        camera_frames = int(self.duration_s / camera_period_s + 1e-6) + 1
        frames = len(self.frame_paths)
        frame_dt = np.diff(self.frame_t_s)
        frame_period = float(np.median(frame_dt)) if len(frame_dt) else math.nan
        logged = self.logged_feature_frames(camera_period_s)
        if logged is None and frames < camera_frames - 1:
            reasons.append(
                f"{frames} of {camera_frames} camera frames saved (one every "
                f"{frame_period:g} s): the clustering sees no image between them"
            )
        return {
            "exact": not reasons,
            "log_period_s": log_period,
            "frame_period_s": frame_period,
            "frames": frames,
            "camera_frames": camera_frames,
            "feature_frames": 0 if self.features is None else len(self.features),
            "features": "logged" if logged is not None else "images",
            "reasons": reasons,
        }

    def logged_feature_frames(self, camera_period_s: float) -> int | None:
        """How many camera frames' features the log holds when it holds those of every frame
        at ``camera_period_s`` (then a replay uses them instead of the images), else None."""
        if self.features is None or not len(self.features):
            return None
        camera_frames = int(self.duration_s / camera_period_s + 1e-6) + 1
        if len(self.features) < camera_frames - 1:
            return None
        if np.any(np.diff(self.feature_t_s) > camera_period_s * (1 + 1e-6)):
            return None
        return len(self.features)

    def features_at(self, t_s: float) -> np.ndarray:
        """The logged features of the newest frame captured strictly before ``t_s`` (the
        first from its own capture time on, as :meth:`frame_at`; NaN before it)."""
        k = int(np.searchsorted(self.feature_t_s, t_s - _EPS_S, side="left")) - 1
        if k < 0 and t_s >= self.feature_t_s[0] - _EPS_S:
            k = 0
        if k < 0:
            return np.full(self.features.shape[1], math.nan)
        return self.features[k]

    def _row_at(self, t_s: float) -> int:
        return max(0, int(np.searchsorted(self.t_s, t_s + _EPS_S, side="right")) - 1)

    def _sample_at(self, t_s: float) -> int:
        """The newest fitter sample at or before ``t_s`` (-1: none, or no samples)."""
        if self.sample_t_s is None:
            return -1
        return int(np.searchsorted(self.sample_t_s, t_s + _EPS_S, side="right")) - 1

    def state_at(self, t_s: float) -> np.ndarray:
        """The state at ``t_s``: the fitter's sample or the row taken at exactly ``t_s`` (the
        two rates' event times can differ in the last bit, 0.15 and 0.15000000000000002, and the
        simulator steps to each), else the newest sample (or row) before it."""
        if self.sample_t_s is not None:
            k = int(np.searchsorted(self.sample_t_s, t_s))
            if k < len(self.sample_t_s) and self.sample_t_s[k] == t_s:
                return self.sample_states[k]
            r = int(np.searchsorted(self.t_s, t_s))
            if r < len(self.t_s) and self.t_s[r] == t_s:
                return self.states[r]
        k = self._sample_at(t_s)
        return self.sample_states[k] if k >= 0 else self.states[self._row_at(t_s)]

    def actuation_before(self, t_s: float) -> np.ndarray:
        """The input applied just before ``t_s``: the one the fitter read at the newest sample
        at or before ``t_s`` (read before that instant's updates), else the newest row's
        strictly before ``t_s``."""
        k = self._sample_at(t_s)
        if k >= 0:
            return self.sample_actuations[k]
        k = int(np.searchsorted(self.t_s, t_s - _EPS_S, side="left")) - 1
        return self.actuations[k] if k >= 0 else np.zeros(self.actuations.shape[1])

    def true_state_at(self, t_s: float) -> np.ndarray:
        """The true state of the row at ``t_s`` (NaN without one)."""
        if self.true_states is None:
            return np.full(len(STATE_NAMES), math.nan)
        return self.true_states[self._row_at(t_s)]

    def truth_at(self, t_s: float) -> tuple[float, float]:
        """(mu_true, terrain_index) of the row at ``t_s`` (NaN, -1 without truth)."""
        if self.mu_true is None:
            return math.nan, -1.0
        k = self._row_at(t_s)
        terrain = self.terrain_index[k] if self.terrain_index is not None else -1.0
        return float(self.mu_true[k]), float(terrain)

    def frame_at(self, t_s: float) -> int:
        """Index of the newest frame captured strictly before ``t_s`` (the first frame from its
        own capture time on; -1: none yet). Strictly: a camera's output at the instant of a
        frame still holds the previous frame until the camera's update at that instant, and
        whatever reads the camera after the update (the features, 1 ms later) sees the new
        one."""
        k = int(np.searchsorted(self.frame_t_s, t_s - _EPS_S, side="left")) - 1
        if k < 0 and len(self.frame_t_s) and t_s >= self.frame_t_s[0] - _EPS_S:
            return 0
        return k

    @classmethod
    def from_frame(
        cls,
        log: pd.DataFrame,
        folder: Path,
        *,
        camera_period_s: float | None = None,
        source: str = "",
    ) -> ReplayLog:
        """From a validated drive-log DataFrame whose ``image`` paths are relative to
        ``folder``; ``camera_period_s`` given: frames saved by ``pcvfe simulate`` (capture time
        from the logger's rule), None: frames at their row's time."""
        t = log["t"].to_numpy(float)
        states = log[list(STATE_NAMES)].to_numpy(float)
        actuations = log[list(INPUT_NAMES)].to_numpy(float)
        mu_true = terrain_index = None
        if "mu_true" in log.columns and np.isfinite(log["mu_true"].to_numpy(float)).any():
            mu_true = log["mu_true"].to_numpy(float)
            if "terrain_index" in log.columns:
                terrain_index = log["terrain_index"].to_numpy(float)
        true_states = None
        if all(c in log.columns for c in TRUE_STATE_COLUMNS):
            values = log[list(TRUE_STATE_COLUMNS)].to_numpy(float)
            true_states = values if np.isfinite(values).any() else None
        frame_t, paths = [], []
        if "image" in log.columns:
            for r, name in zip(t, log["image"].astype(str), strict=True):
                if not name or name == "nan":
                    continue
                path = Path(name) if Path(name).is_absolute() else folder / name
                if not path.is_file():
                    raise FileNotFoundError(f"replay {source}: camera frame {path} is missing")
                frame_t.append(capture_time(r, camera_period_s))
                paths.append(path)
        frame_t = np.asarray(frame_t, dtype=float)
        # Two rows may carry the same capture (the first two of a run): keep the first.
        keep = np.concatenate([[True], np.diff(frame_t) > _EPS_S]) if len(frame_t) else []
        feature_t, features = _logged_features(log, camera_period_s)
        return cls(
            t_s=t,
            states=states,
            actuations=actuations,
            frame_t_s=frame_t[keep] if len(frame_t) else frame_t,
            frame_paths=[p for p, k in zip(paths, keep, strict=True) if k],
            mu_true=mu_true,
            terrain_index=terrain_index,
            source=source,
            true_states=true_states,
            feature_t_s=feature_t,
            features=features,
        )

    @classmethod
    def from_run_folder(cls, folder: str | Path, camera_period_s: float) -> ReplayLog:
        """The drive of a ``pcvfe simulate`` (or ``pcvfe replay``) run folder."""
        folder = Path(folder)
        path = folder / "drive_log.csv"
        if not path.is_file():
            raise FileNotFoundError(f"replay: {folder} has no drive_log.csv (not a run folder?)")
        log = cls.from_frame(
            read_drive_log(path), folder, camera_period_s=camera_period_s, source=str(folder)
        )
        samples = folder / SAMPLES_FILE
        if samples.is_file():
            log.sample_t_s, log.sample_states, log.sample_actuations = read_samples(samples)
        return log

    @classmethod
    def from_drive_log(cls, path: str | Path) -> ReplayLog:
        """A drive log file (e.g. from ``pcvfe import-bag``): frames at their rows' times."""
        path = Path(path)
        return cls.from_frame(read_drive_log(path), path.parent, source=str(path))


def read_samples(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t_s, state, actuation)`` of a run's :data:`SAMPLES_FILE`; a ValueError naming the
    file when it cannot be read or its arrays do not fit together."""
    try:
        with np.load(path, allow_pickle=False) as data:
            t, x, u = (np.asarray(data[k], dtype=float) for k in ("t_s", "state", "actuation"))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"replay: {path}: not a readable samples file ({exc})") from exc
    ok = (
        t.ndim == 1
        and x.shape == (t.size, len(STATE_NAMES))
        and u.shape == (t.size, len(INPUT_NAMES))
        and np.all(np.isfinite(t))
        and np.all(np.diff(t) > 0)
    )
    if not ok:
        raise ValueError(
            f"replay: {path}: arrays t_s {t.shape}, state {x.shape}, actuation {u.shape} do not "
            "fit together (increasing times, 7 states and 2 inputs per sample)"
        )
    return t, x, u


def _logged_features(
    log: pd.DataFrame, camera_period_s: float | None
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Capture times and features of the frames whose features a run logged (``f_00``...
    columns, each row holding those of the frame taken before it): one per capture, rows
    without finite features skipped; (None, None) without such columns or a camera period."""
    columns = [c for c in log.columns if re.fullmatch(r"f_\d+", str(c))]
    columns.sort(key=lambda c: int(c[2:]))
    if not columns or camera_period_s is None:
        return None, None
    values = log[columns].to_numpy(float)
    capture = np.array([capture_time(r, camera_period_s) for r in log["t"].to_numpy(float)])
    finite = np.all(np.isfinite(values), axis=1)
    capture, values = capture[finite], values[finite]
    if not len(capture):
        return None, None
    first = np.concatenate([[True], np.diff(capture) > _EPS_S])
    return capture[first], values[first]


def capture_time(row_t_s: float, camera_period_s: float | None) -> float:
    """When the frame saved with the row at ``row_t_s`` was taken (see the module doc)."""
    if camera_period_s is None or row_t_s <= _EPS_S:
        return float(row_t_s)
    k = math.ceil(row_t_s / camera_period_s - 1e-6) - 1
    return max(0.0, k * camera_period_s)
