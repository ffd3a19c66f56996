"""A drive log prepared for the workbench: arrays, contexts, noise scales, splits and windows."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pcvfe_drake.runs.drivelog import REQUIRED_COLUMNS, read_drive_log, validate_drive_log
from pcvfe_drake.runs.resample import resample_log
from pcvfe_drake.vehicle.single_track import STATE_NAMES

MIN_DURATION_S = 20.0
"""Shortest log the workbench accepts [s]: it needs training and held-out blocks of windows."""
MIN_SPEED_MPS = 1.0
"""Windows are used only where the measured speed stays at or above this [m/s] (the ST model is
stiff and its friction is unobservable near standstill; the paper filters the same way)."""
MAX_DT_JITTER = 0.05
"""Largest relative deviation of a time step from the median step."""
NOISE_STRIDE_S = 0.1
"""Noise scales are estimated from 4th differences over strides of up to this time [s]."""
CORRELATED_NOISE_RATIO = 1.15
"""A longer-stride noise estimate this much above the 1-sample one means correlated noise."""
EXCITATION_NOISE_FACTOR = 5.0
"""A signal is excited when its standard deviation exceeds this many times its noise (the
fitter's fit-percent test and the workbench's excitation check share it)."""
LOG_SUFFIXES = (".csv", ".csv.gz", ".parquet", ".pq")
MAX_SAMPLES = 30_000
"""Most samples the workbench analyses (bounded memory and time; 5 min at 100 Hz). A longer log
is analysed on ``EXCERPTS`` excerpts of ``MAX_SAMPLES // EXCERPTS`` consecutive samples, evenly
spaced over the log (first and last included): see :func:`excerpt_rows`."""
EXCERPTS = 6
"""Excerpts of a long log; equal to the default number of time blocks, so that each excerpt is
one block and no window, block or free run spans the gap between two excerpts."""


def find_log(path: str | Path) -> Path:
    """``path`` itself if it is a file; in a run folder the one drive log it holds."""
    p = Path(path)
    if p.is_file():
        return p
    if p.is_dir():
        found = sorted(
            q for q in p.rglob("*") if q.is_file() and q.name.lower().endswith(LOG_SUFFIXES)
        )
        preferred = [q for q in found if q.stem.split(".")[0] in ("log", "drive_log", "drivelog")]
        if len(preferred) == 1:
            return preferred[0]
        if len(found) == 1:
            return found[0]
        if not found:
            raise FileNotFoundError(f"run folder {p}: no drive log (*.csv, *.parquet) inside")
        names = ", ".join(str(q.relative_to(p)) for q in found[:8])
        raise ValueError(f"run folder {p}: several drive logs ({names}); name one of them")
    raise FileNotFoundError(f"drive log {p}: no such file or folder")


def robust_noise_sigma(y: np.ndarray, max_stride: int = 1) -> float:
    """Measurement-noise standard deviation of a smooth signal from its 4th differences.

    For white noise of std s the 4th difference has std ``s sqrt(70)``; the median absolute
    deviation makes the estimate robust to the few samples where the signal itself bends.
    Noise that is correlated over a few samples (a log interpolated to a higher rate) makes
    neighbouring differences cancel; the 4th differences are therefore also taken over every
    ``stride``-th sample (1..``max_stride``), and the largest estimate replaces the one of
    stride 1 when it exceeds it by more than ``CORRELATED_NOISE_RATIO`` (for white noise they
    agree within a few percent).
    """
    return float(robust_noise_sigmas(np.asarray(y)[:, None], max_stride)[0])


def robust_noise_sigmas(y: np.ndarray, max_stride: int = 1) -> np.ndarray:
    """:func:`robust_noise_sigma` of each column of ``y`` (n, k), (k,): the same numbers, the
    differences and medians of all columns taken in one array operation each (the context
    fitter estimates the noise of its whole buffer at every refit)."""
    y = np.asarray(y, dtype=float)
    # The differences and medians run along the rows of the transposed, contiguous copy: the
    # same elementwise arithmetic and the same order statistics as along ``y``'s columns (so
    # the same numbers), at a fraction of the cost of partitioning strided columns.
    yt = np.ascontiguousarray(y.T)
    estimates = []
    for stride in range(1, max(1, int(max_stride)) + 1):
        d4 = _fourth_differences(yt, stride, 0, yt.shape[1] - 4 * stride)
        if d4.shape[1] < 5:
            break
        dev = np.abs(d4 - np.median(d4, axis=1, keepdims=True))
        mad = np.median(dev, axis=1, overwrite_input=True)
        estimates.append(sigma_from_fourth_difference_mad(mad))
    return combine_stride_estimates(estimates, y)


def sigma_from_fourth_difference_mad(mad):
    """White noise's standard deviation from the median absolute deviation of its 4th
    differences: the MAD of a normal variable is 1/1.4826 of its std, and the 4th difference
    of white noise of std s has std ``s sqrt(70)``."""
    return 1.4826 * mad / np.sqrt(70.0)


def combine_stride_estimates(estimates: list, y: np.ndarray) -> np.ndarray:
    """The noise scales from the per-stride estimates (stride 1 first): the largest where it
    exceeds stride 1's by ``CORRELATED_NOISE_RATIO`` (correlated noise), else stride 1's; with
    no estimate (too few samples) the columns' standard deviations (1 where constant)."""
    if not estimates:
        out = np.std(y, axis=0)
        return np.where(out == 0.0, 1.0, out)
    top = np.max(estimates, axis=0)
    return np.where(top > CORRELATED_NOISE_RATIO * estimates[0], top, estimates[0])


def _fourth_differences(yt: np.ndarray, stride: int, lo: int, hi: int) -> np.ndarray:
    """The 4th differences over ``stride`` samples of the rows of ``yt`` (k, n) that start at
    samples ``lo..hi-1`` (k, hi - lo): one expression for :func:`robust_noise_sigmas` and
    :class:`NoiseScaleCache`, so that both give each difference the same bits."""
    s = stride
    d4 = yt[:, lo + 4 * s : hi + 4 * s] - 4 * yt[:, lo + 3 * s : hi + 3 * s]
    d4 = d4 + 6 * yt[:, lo + 2 * s : hi + 2 * s]
    return d4 - 4 * yt[:, lo + s : hi + s] + yt[:, lo:hi]


def _sorted_mads(values: np.ndarray) -> np.ndarray:
    """``np.median(np.abs(v - np.median(v)))`` of each sorted, finite row ``v`` of ``values``
    (k, m), from order statistics alone (``noise_kernel.sorted_mads``)."""
    from pcvfe_drake.models.noise_kernel import sorted_mads

    return sorted_mads(np.ascontiguousarray(values, dtype=float))


class NoiseScaleCache:
    """:func:`robust_noise_sigmas` of a buffer that changes by a few samples between calls
    (new samples at its end, old ones dropped from its start), with the same numbers and only
    new work: the 4th differences of the samples kept are kept, sorted, and the new ones are
    merged in; the medians and the median absolute deviations come from the sorted values.

    Why: the context fitter estimates the noise of its whole buffer (60 s) at every refit,
    though between two refits of a context it gained a second of samples and lost as many;
    recomputing every difference and partitioning every column took most of the refit's data
    preparation. Exactness: a difference is reused only when the samples it is made of are
    bit for bit the samples it was made of (the overlap with the last call is compared); the
    medians of a multiset do not depend on its order. Anything else (another stride count,
    non-finite values, a buffer that does not continue the last one) recomputes from scratch.
    """

    def __init__(self) -> None:
        self._last: tuple | None = None
        """The last call's ``(t, y transposed, max_stride, sorted)``, ``sorted`` per stride the
        4th differences of each column, sorted (k, n - 4 stride). One tuple, replaced whole:
        copies of an estimator share the cache, and each call reads one consistent state."""

    def sigmas(self, t: np.ndarray, y: np.ndarray, max_stride: int = 1) -> np.ndarray:
        """:func:`robust_noise_sigmas` ``(y, max_stride)``; ``t`` the samples' times [s] (n,),
        by which the samples kept from the last call are found."""
        t = np.asarray(t, dtype=float)
        y = np.asarray(y, dtype=float)
        max_stride = max(1, int(max_stride))
        n = y.shape[0]
        if y.ndim != 2 or t.shape != (n,) or n < 4 * max_stride + 5 or not np.isfinite(y).all():
            self._last = None
            return robust_noise_sigmas(y, max_stride)
        yt = np.ascontiguousarray(y.T)
        last = self._last
        drop = _continued(last, t, yt, max_stride)
        if drop is None:
            ordered = [
                np.sort(_fourth_differences(yt, s, 0, n - 4 * s), axis=1)
                for s in range(1, max_stride + 1)
            ]
        else:
            old_yt, old_sorted = last[1], last[3]
            old_n = old_yt.shape[1]
            ordered = [
                _merge_differences(
                    old_sorted[s - 1],
                    _fourth_differences(old_yt, s, 0, min(drop, old_n - 4 * s)),
                    _fourth_differences(yt, s, max(0, old_n - drop - 4 * s), n - 4 * s),
                )
                for s in range(1, max_stride + 1)
            ]
        self._last = (t.copy(), yt, max_stride, ordered)
        estimates = [sigma_from_fourth_difference_mad(_sorted_mads(v)) for v in ordered]
        return combine_stride_estimates(estimates, y)


def _continued(last: tuple | None, t: np.ndarray, yt: np.ndarray, max_stride: int) -> int | None:
    """How many of the last call's samples were dropped from its start, where this buffer
    continues it (its samples from there on the last call's, bit for bit, then new ones);
    None where it does not."""
    if last is None:
        return None
    old_t, old_yt, old_stride, _ = last
    if max_stride != old_stride or yt.shape[0] != old_yt.shape[0]:
        return None
    drop = int(np.searchsorted(old_t, t[0], side="left"))
    kept = old_t.size - drop
    if drop >= old_t.size or kept > t.size or kept < 4 * max_stride + 5:
        return None
    same = np.array_equal(old_t[drop:].view(np.int64), t[:kept].view(np.int64))
    same = same and np.array_equal(old_yt[:, drop:].view(np.int64), yt[:, :kept].view(np.int64))
    return drop if same else None


def _merge_differences(values: np.ndarray, gone: np.ndarray, new: np.ndarray) -> np.ndarray:
    """The sorted rows of ``values`` (k, m) without the values ``gone`` (k, g; each present)
    and with the values ``new`` (k, a), still sorted (``noise_kernel.merge_rows``: one pass
    per row)."""
    from pcvfe_drake.models.noise_kernel import merge_rows

    return merge_rows(
        np.ascontiguousarray(values, dtype=float),
        np.ascontiguousarray(gone, dtype=float),
        np.ascontiguousarray(new, dtype=float),
    )


@dataclass
class DriveData:
    """Arrays of one drive log.

    Attributes:
        t: sample times [s] (n,).
        dt: the (uniform) sample step [s].
        x: measured ST states (n, 7), psi unwrapped.
        u: commanded inputs (n, 2) [steer_rate rad/s, accel m/s^2].
        context: context index per sample (n,) into ``context_names``.
        context_names: labels of the contexts.
        sigma: noise scale per state (7,) used to whiten errors.
        source: a name for messages.
        x0: states used to *start* rollouts (n, 7): the measurements, with the steering angle
            denoised (see :func:`initial_state_estimates`).
        rows_in_log: samples of the whole log (more than ``n`` when only excerpts are analysed).
        x0_delta_sigma: noise [rad] left on the denoised steering angle of ``x0``
            (see :func:`denoised_delta_sigma`).
    """

    t: np.ndarray
    dt: float
    x: np.ndarray
    u: np.ndarray
    context: np.ndarray
    context_names: list[str]
    sigma: np.ndarray
    source: str = "<log>"
    x0: np.ndarray | None = None
    rows_in_log: int | None = None
    x0_delta_sigma: float | None = None

    def __post_init__(self) -> None:
        if self.rows_in_log is None:
            self.rows_in_log = int(self.t.size)
        if self.x0 is None:
            self.x0 = initial_state_estimates(self.x, self.u, self.dt)
        if self.x0_delta_sigma is None:
            self.x0_delta_sigma = denoised_delta_sigma(self.x, self.u, self.dt)

    @property
    def n(self) -> int:
        return self.t.size

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])


INIT_HALF_WINDOW_S = 0.25
"""Half width [s] of the window over which the initial steering angle is averaged."""


def initial_state_estimates(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """Measured states with the steering angle denoised for use as rollout initial states.

    The steering angle is the integral of the commanded steering rate, so
    ``delta(j) - sum(steer_rate dt, s..j)`` estimates ``delta(s)`` for every j near s; their
    mean over +-``INIT_HALF_WINDOW_S`` removes most of the measurement noise. This matters:
    an initial angle error is amplified into a persistent yaw-rate error (v delta / L) over a
    whole window. The other states start from their measurements.
    """
    x0 = x.copy()
    m = max(1, int(round(INIT_HALF_WINDOW_S / dt)))
    n = x.shape[0]
    cum = np.concatenate([[0.0], np.cumsum(u[:-1, 0] * dt)])
    offset = x[:, 2] - cum  # delta(j) - C(j); estimate of delta(s) is mean(offset) + C(s)
    csum = np.concatenate([[0.0], np.cumsum(offset)])
    lo = np.clip(np.arange(n) - m, 0, n)
    hi = np.clip(np.arange(n) + m + 1, 0, n)
    x0[:, 2] = (csum[hi] - csum[lo]) / (hi - lo) + cum
    return x0


def excerpt_rows(n: int, max_samples: int = MAX_SAMPLES, excerpts: int = EXCERPTS) -> np.ndarray:
    """Row indices the workbench analyses of an ``n``-sample log: all rows if ``n <=
    max_samples``, else ``excerpts`` runs of ``max_samples // excerpts`` consecutive rows whose
    starts are evenly spaced from row 0 to the last possible start."""
    if n <= max_samples:
        return np.arange(n)
    m = max_samples // excerpts
    starts = np.linspace(0, n - m, excerpts).round().astype(np.int64)
    return (starts[:, None] + np.arange(m)[None, :]).reshape(-1)


def denoised_delta_sigma(x: np.ndarray, u: np.ndarray, dt: float) -> float:
    """Noise [rad] left on the denoised initial steering angle of :func:`initial_state_estimates`.

    ``delta(j) - sum(steer_rate dt)`` is a constant plus the angle's measurement noise, so the
    difference of its means over two adjacent windows of the averaging width is noise alone;
    its robust spread / sqrt(2) is the noise of one window mean. Unlike ``sigma / sqrt(width)``
    this holds for noise correlated over several samples (an interpolated, upsampled log).
    """
    m = max(1, int(round(INIT_HALF_WINDOW_S / dt)))
    width = 2 * m + 1
    cum = np.concatenate([[0.0], np.cumsum(u[:-1, 0] * dt)])
    offset = x[:, 2] - cum
    n_win = offset.size // width
    if n_win < 6:
        return float(robust_noise_sigma(x[:, 2]) / np.sqrt(width))
    means = offset[: n_win * width].reshape(n_win, width).mean(axis=1)
    d = np.diff(means)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def choose_context_column(df: pd.DataFrame, column: str | None) -> str | None:
    if column is not None:
        if column not in df.columns:
            raise ValueError(
                f"context column {column!r} is not in the log (columns: {', '.join(df.columns)})"
            )
        return column
    for name in ("context", "terrain"):
        if name in df.columns:
            return name
    return None


def prepare(
    df: pd.DataFrame,
    source: str = "<DataFrame>",
    context_column: str | None = None,
    min_duration_s: float = MIN_DURATION_S,
    max_samples: int | None = MAX_SAMPLES,
    check_units: bool = True,
) -> DriveData:
    """Validate a drive-log table and convert it to :class:`DriveData`.

    A log of more than ``max_samples`` rows is validated whole and analysed on the excerpts of
    :func:`excerpt_rows` (initial states and noise scales come from the whole log); ``None``:
    every row. ``check_units=False`` skips the drive-log validator's unit heuristics (ranges
    and consistency that suggest degrees or km/h); the format checks always run.

    Raises:
        ValueError: (a ``DriveLogError`` for format problems) with the input and value named.
    """
    validate_drive_log(df, source=source, check_units=check_units)
    t = df["t"].to_numpy(dtype=float)
    if t.size < 10 or t[-1] - t[0] < min_duration_s:
        raise ValueError(
            f"drive log {source}: too short ({t[-1] - t[0]:.3g} s, {t.size} rows); the workbench "
            f"needs at least {min_duration_s:g} s for training and held-out blocks"
        )
    steps = np.diff(t)
    dt = float(np.median(steps))
    jitter = np.abs(steps - dt) / dt
    if np.any(jitter > MAX_DT_JITTER):
        i = int(np.argmax(jitter))
        raise ValueError(
            f"drive log {source}: column 't' is not uniformly sampled (step {steps[i]:.4g} s at "
            f"row {i + 1} vs median {dt:.4g} s); resample the log to a fixed rate (--resample HZ, "
            "or pcvfe_drake.runs.resample.resample_log)"
        )
    x = df[list(STATE_NAMES)].to_numpy(dtype=float).copy()
    x[:, 4] = np.unwrap(x[:, 4])
    u = df[list(REQUIRED_COLUMNS[-2:])].to_numpy(dtype=float).copy()
    col = choose_context_column(df, context_column)
    if col is None:
        context = np.zeros(t.size, dtype=int)
        names = ["all"]
    else:
        labels = df[col].map(lambda s: "" if pd.isna(s) else str(s)).to_numpy()
        names = sorted(set(labels), key=str)
        lookup = {name: i for i, name in enumerate(names)}
        context = np.array([lookup[s] for s in labels], dtype=int)
        names = [s if s != "" else "unknown" for s in names]
    strides = max(1, int(round(NOISE_STRIDE_S / dt)))
    sigma = robust_noise_sigmas(x, strides)
    spread = np.maximum(np.ptp(x, axis=0), 1e-6)
    sigma = np.maximum(sigma, 1e-4 * spread)
    x0 = initial_state_estimates(x, u, dt)
    x0_sigma = denoised_delta_sigma(x, u, dt)
    rows = excerpt_rows(t.size, max_samples) if max_samples else np.arange(t.size)
    if rows.size == t.size:
        return DriveData(t, dt, x, u, context, names, sigma, source, x0, x0_delta_sigma=x0_sigma)
    return DriveData(
        t[rows],
        dt,
        x[rows],
        u[rows],
        context[rows],
        names,
        sigma,
        source,
        x0[rows],
        t.size,
        x0_delta_sigma=x0_sigma,
    )


def load(
    path: str | Path,
    context_column: str | None = None,
    min_duration_s: float = MIN_DURATION_S,
    resample_hz: float | None = None,
    check_units: bool = True,
) -> DriveData:
    """Read and prepare a drive log file or run folder.

    Args:
        resample_hz: resample to this rate first (:func:`pcvfe_drake.runs.resample.resample_log`).
        check_units: False skips the unit heuristics (a user who knows the log is right).
    """
    p = find_log(path)
    df = read_drive_log(p, check_units=check_units, max_gap_s=None)
    if resample_hz is not None:
        df = resample_log(df, resample_hz, source=str(p))
    return prepare(df, str(p), context_column, min_duration_s, check_units=check_units)


def block_ids(n: int, n_blocks: int) -> np.ndarray:
    """Consecutive time-block index (0..n_blocks-1) of each sample."""
    return np.minimum((np.arange(n) * n_blocks) // n, n_blocks - 1)


def heldout_blocks(n_blocks: int) -> np.ndarray:
    """Held-out blocks: every third block starting with the second (1, 4, 7, ...)."""
    return np.arange(1, n_blocks, 3)


def window_starts(
    data: DriveData, horizon: int, stride: int, split: str, n_blocks: int = 6
) -> np.ndarray:
    """Start samples of windows of ``horizon`` steps lying inside one time block of the split
    (``"train"``, ``"heldout"`` or ``"all"``), one context, with speed >= ``MIN_SPEED_MPS``."""
    blocks = block_ids(data.n, n_blocks)
    held = np.isin(blocks, heldout_blocks(n_blocks))
    if split == "train":
        use = ~held
    elif split == "heldout":
        use = held
    elif split == "all":
        use = np.ones(data.n, bool)
    else:
        raise ValueError(f"split must be 'train', 'heldout' or 'all', got {split!r}")
    starts = np.arange(0, data.n - horizon, max(1, stride))
    if starts.size == 0:
        return starts
    idx = starts[:, None] + np.arange(horizon + 1)[None, :]
    steady = np.abs(np.diff(data.t) - data.dt) <= 0.5 * data.dt  # no gap between excerpts
    ok = (
        steady[idx[:, :-1]].all(axis=1)
        & use[idx].all(axis=1)
        & (blocks[idx] == blocks[idx[:, :1]]).all(axis=1)
        & (data.context[idx] == data.context[idx[:, :1]]).all(axis=1)
        & (data.x[idx, 3] >= MIN_SPEED_MPS).all(axis=1)
    )
    return starts[ok]
