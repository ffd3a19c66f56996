"""Training windows for context-specific friction fitting (paper eq. 5b-5d and 6).

A window of horizon ``H`` starting at sample ``s`` holds the measured state ``x[s]`` (the initial
condition, eq. 5b), the inputs ``u[s], ..., u[s+H-1]`` (held for one step each, eq. 5c) and the
measured states ``x[s+1], ..., x[s+H]`` that the rollout must predict. Candidate windows start
every ``stride`` samples; a window is kept only if all of its ``H + 1`` samples

1. are finite (state, input and time; the input of the last sample is not used),
2. are evenly spaced: every step within ``dt_rel_tol`` of the nominal step ``dt`` (a gap or a
   jitter breaks the zero-order-hold assumption of the rollout),
3. carry one context label (eq. 5d: the window stays in one terrain context),
4. carry a known context (not ``-1``/NaN/empty: noise and unknown contexts are not fitted),
5. have ``v >= v_min`` (eq. 6; default 1 m/s, where the ST model is well conditioned).

Rejected windows are counted under the first reason that applies, in the order above
(``non_finite``, ``time_gap``, ``context_change``, ``no_context``, ``low_speed``).

Bounded memory (``max_windows``): a context with more kept windows than ``max_windows`` is fitted
on ``max_windows`` of them, evenly spaced over all of its kept windows in time order (the i-th of
``max_windows`` is kept window ``round(i (n - 1) / (max_windows - 1))``); the others are counted
in ``WindowSplit.available``. A fit holds its windows, residuals and Jacobians, about 15 KB per
window at H = 10, so the cap bounds its memory whatever the length of the log. The default
(``DEFAULT_MAX_WINDOWS`` = 20,000 windows, 1.4 million residuals, ~17 minutes of driving at
100 Hz and stride 5) keeps the statistical error of mu far below the bias of any model error;
the reported standard deviations are those of the windows used.

Initial-state smoothing (a documented departure from eq. 5b): with noisy measurements, starting
the rollout from the measured state is an errors-in-variables problem. The noise in the initial
yaw rate and side slip decays at a rate that grows with mu, so the fit prefers a larger mu to
shed it faster: with the noise model of ``pcvfe_drake.models.synthetic_drive`` and H = 10 this
biases mu
by +0.01 to +0.02. By default the initial steering angle, yaw rate and side slip of a window are
therefore the mean of the ``2 m + 1`` samples centred on the start, with
``m = round(x0_smoothing_s / dt)`` (default 0.03 s: m = 3, 7 samples at 100 Hz; m = 0 at 10 Hz),
where those samples are finite, evenly spaced and in the same context (else the raw measurement
is used). This removes the bias to within the scatter (measured: |mean error| <= 0.003) and costs
at most ~0.002 on noise-free S-curve data. ``x0_smoothing_s=0`` gives eq. 5b exactly.

State order is the project's (``pcvfe_drake.vehicle.single_track``): [sx, sy, delta, v, psi,
psi_dot, beta];
inputs are [steer_rate, accel].
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from pcvfe_drake.vehicle.single_track import BETA, DELTA, NU, NX, PSI_DOT, STATE_NAMES, V

SKIP_REASONS = ("non_finite", "time_gap", "context_change", "no_context", "low_speed")
"""Reasons a candidate window is skipped, in the order they are checked."""

STATE_COLUMNS = STATE_NAMES
INPUT_COLUMNS = ("steer_rate", "accel")

DEFAULT_HORIZON = 10
"""Window length H [steps] (the public PC-VFE implementation's)."""
DEFAULT_STRIDE = 5
"""Samples between window starts (the public PC-VFE implementation's)."""
DEFAULT_V_MIN_MPS = 1.0
"""Speed filter of eq. 6 [m/s]."""
DEFAULT_DT_REL_TOL = 0.1
"""Allowed relative deviation of a time step from the nominal step."""
DEFAULT_X0_SMOOTHING_S = 0.03
"""Half-width [s] of the mean that smooths a window's initial delta, psi_dot and beta."""
DEFAULT_MAX_WINDOWS = 20_000
"""Most windows fitted per context (see "Bounded memory" in the module docstring)."""
SMOOTHED_STATES = (DELTA, PSI_DOT, BETA)
"""States whose initial value is smoothed (see the module docstring)."""


@dataclass(frozen=True)
class WindowDataset:
    """Windows of one context.

    Attributes:
        x0: measured initial states, (B, 7).
        U: inputs [steer_rate, accel], (B, H, 2), ``U[:, k]`` held over step k.
        X: measured states to predict at steps 1..H, (B, H, 7).
        dt: step [s].
        start: index of each window's first sample in the source arrays, (B,).
        t0: time of each window's first sample [s], (B,).
    """

    x0: np.ndarray
    U: np.ndarray
    X: np.ndarray
    dt: float
    start: np.ndarray
    t0: np.ndarray

    @property
    def n_windows(self) -> int:
        return int(self.x0.shape[0])

    @property
    def horizon(self) -> int:
        return int(self.U.shape[1])

    def subset(self, index) -> WindowDataset:
        """The windows selected by ``index`` (an index array, slice or boolean mask)."""
        return WindowDataset(
            x0=self.x0[index],
            U=self.U[index],
            X=self.X[index],
            dt=self.dt,
            start=self.start[index],
            t0=self.t0[index],
        )

    @staticmethod
    def concatenate(parts: list[WindowDataset]) -> WindowDataset:
        """Windows of several datasets with the same step and horizon, in order."""
        if not parts:
            raise ValueError("WindowDataset.concatenate: no datasets given")
        dt = parts[0].dt
        for p in parts[1:]:
            if abs(p.dt - dt) > 1e-9 * dt or p.horizon != parts[0].horizon:
                raise ValueError(
                    f"WindowDataset.concatenate: dt/horizon differ ({p.dt}/{p.horizon} vs "
                    f"{dt}/{parts[0].horizon})"
                )
        return WindowDataset(
            x0=np.concatenate([p.x0 for p in parts]),
            U=np.concatenate([p.U for p in parts]),
            X=np.concatenate([p.X for p in parts]),
            dt=dt,
            start=np.concatenate([p.start for p in parts]),
            t0=np.concatenate([p.t0 for p in parts]),
        )


@dataclass
class WindowSplit:
    """The result of window building: kept windows per context and skip counts.

    Attributes:
        by_context: context label -> windows of that context (only contexts with windows).
        skipped: reason -> number of skipped candidate windows (every reason present).
        n_candidates: candidate windows examined.
        dt: nominal step [s] the windows use.
        horizon: H [steps].
        samples: context label -> number of samples carrying that label (all contexts seen).
        skipped_by_context: context label -> reason -> skipped windows whose first sample
            carries that label (windows starting in an unknown context are not attributed).
        available: context label -> kept windows before the ``max_windows`` cap (equal to the
            windows in ``by_context`` when the cap did not apply).
    """

    by_context: dict[Hashable, WindowDataset]
    skipped: dict[str, int]
    n_candidates: int
    dt: float
    horizon: int
    samples: dict[Hashable, int] = field(default_factory=dict)
    skipped_by_context: dict[Hashable, dict[str, int]] = field(default_factory=dict)
    available: dict[Hashable, int] = field(default_factory=dict)

    @property
    def n_windows(self) -> int:
        return sum(d.n_windows for d in self.by_context.values())


def _context_codes(contexts, n: int, default_label: Hashable):
    """Integer codes per sample (-1 = no context) and the code -> label list."""
    if contexts is None:
        return np.zeros(n, dtype=np.int64), [default_label]
    ctx = np.asarray(contexts)
    if ctx.shape != (n,):
        raise ValueError(f"contexts must have shape ({n},), got {ctx.shape}")
    if ctx.dtype.kind in "iub":
        values = ctx.astype(np.int64)
        unknown = values < 0
    elif ctx.dtype.kind == "f":
        unknown = ~np.isfinite(ctx) | (ctx < 0)
        values = np.where(unknown, -1, np.round(np.nan_to_num(ctx, nan=-1.0))).astype(np.int64)
        bad = ~unknown & (values != ctx)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"contexts: non-integer context id {ctx[i]!r} at sample {i}")
    else:  # labels such as terrain names; None/NaN/"" are unknown
        series = pd.Series(ctx, dtype=object)
        unknown = (series.isna() | (series.astype(str).str.strip() == "")).to_numpy()
        values = np.full(n, -1, dtype=np.int64)
        labels = list(dict.fromkeys(series[~unknown].tolist()))
        lookup = {lab: i for i, lab in enumerate(labels)}
        values[~unknown] = [lookup[v] for v in series[~unknown]]
        return values, labels
    uniq = sorted(set(values[~unknown].tolist()))
    lookup = {lab: i for i, lab in enumerate(uniq)}
    codes = np.full(n, -1, dtype=np.int64)
    codes[~unknown] = [lookup[v] for v in values[~unknown]]
    return codes, [int(u) for u in uniq]


def nominal_step(t: np.ndarray) -> float:
    """The median positive step of the finite time stamps ``t`` [s]."""
    t = np.asarray(t, dtype=float)
    tf = t[np.isfinite(t)]
    steps = np.diff(tf)
    steps = steps[steps > 0]
    if steps.size == 0:
        raise ValueError("t: fewer than two increasing finite time stamps; cannot infer the step")
    return float(np.median(steps))


def _initial_states(states, starts, sample_ok, step_ok, codes, half_width: int) -> np.ndarray:
    """Initial states of the windows starting at ``starts``, smoothed where the data allow."""
    x0 = states[starts].copy()
    if half_width == 0:
        return x0
    n = states.shape[0]
    offsets = np.arange(-half_width, half_width + 1)
    nb = starts[:, None] + offsets[None, :]
    inside = (nb[:, 0] >= 0) & (nb[:, -1] < n)
    nbc = np.clip(nb, 0, n - 1)
    ok = inside & sample_ok[nbc].all(axis=1) & (codes[nbc] == codes[nbc[:, :1]]).all(axis=1)
    ok &= step_ok[np.clip(nbc[:, :-1], 0, max(n - 2, 0))].all(axis=1)
    cols = list(SMOOTHED_STATES)
    rows = np.flatnonzero(ok)
    if rows.size:
        x0[np.ix_(rows, cols)] = states[nbc[rows]][:, :, cols].mean(axis=1)
    return x0


def build_windows(
    t,
    states,
    inputs,
    contexts=None,
    *,
    horizon: int = DEFAULT_HORIZON,
    stride: int = DEFAULT_STRIDE,
    v_min: float = DEFAULT_V_MIN_MPS,
    dt: float | None = None,
    dt_rel_tol: float = DEFAULT_DT_REL_TOL,
    x0_smoothing_s: float = DEFAULT_X0_SMOOTHING_S,
    default_label: Hashable = 0,
    max_windows: int | None = DEFAULT_MAX_WINDOWS,
) -> WindowSplit:
    """Cut sample arrays into fitting windows per context (see the module docstring).

    Args:
        t: sample times [s], (N,), strictly increasing where finite.
        states: measured states, (N, 7), project state order.
        inputs: inputs [steer_rate, accel], (N, 2); ``inputs[i]`` is held from ``t[i]``.
        contexts: optional context label per sample, (N,): integer ids (negative = noise/unknown),
            floats (NaN or negative = unknown) or labels such as terrain names (None/NaN/"" =
            unknown). ``None``: all samples are one context labelled ``default_label``.
        horizon: H, steps per window (>= 1).
        stride: samples between candidate window starts (>= 1).
        v_min: smallest speed allowed in a window [m/s] (eq. 6).
        dt: nominal step [s]; default the median step of ``t``.
        dt_rel_tol: allowed relative deviation of each step from ``dt``.
        x0_smoothing_s: half-width [s] of the centred mean that gives the initial delta,
            psi_dot and beta of each window (rounded to whole samples; 0 = the raw measurement,
            eq. 5b).
        default_label: the label used when ``contexts`` is None.
        max_windows: most windows per context, evenly spaced (see the module docstring);
            ``None``: all.
    Raises:
        ValueError: bad shapes or arguments, or time stamps that do not increase.
    """
    if int(horizon) != horizon or horizon < 1:
        raise ValueError(f"horizon must be an integer >= 1, got {horizon!r}")
    if int(stride) != stride or stride < 1:
        raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
    horizon, stride = int(horizon), int(stride)
    if not np.isfinite(v_min):
        raise ValueError(f"v_min must be finite, got {v_min!r}")
    if not (np.isfinite(dt_rel_tol) and dt_rel_tol >= 0):
        raise ValueError(f"dt_rel_tol must be >= 0, got {dt_rel_tol!r}")
    if not (np.isfinite(x0_smoothing_s) and x0_smoothing_s >= 0):
        raise ValueError(f"x0_smoothing_s must be >= 0 s, got {x0_smoothing_s!r}")
    if max_windows is not None and (int(max_windows) != max_windows or max_windows < 2):
        raise ValueError(f"max_windows must be an integer >= 2 or None, got {max_windows!r}")
    t = np.asarray(t, dtype=float).reshape(-1)
    n = t.shape[0]
    states = np.asarray(states, dtype=float)
    inputs = np.asarray(inputs, dtype=float)
    if states.shape != (n, NX):
        raise ValueError(f"states must have shape ({n}, {NX}) to match t, got {states.shape}")
    if inputs.shape != (n, NU):
        raise ValueError(f"inputs must have shape ({n}, {NU}) to match t, got {inputs.shape}")
    finite_t = np.flatnonzero(np.isfinite(t))
    steps = np.diff(t[finite_t])
    if np.any(steps <= 0):
        i = int(finite_t[1:][np.flatnonzero(steps <= 0)[0]])
        raise ValueError(
            f"t must be strictly increasing: t[{i}]={t[i]!r} s after t[{i - 1}]={t[i - 1]!r} s"
        )
    if dt is None:
        dt = nominal_step(t)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be > 0 s, got {dt!r}")
    codes, labels = _context_codes(contexts, n, default_label)
    samples = {labels[c]: int(np.count_nonzero(codes == c)) for c in range(len(labels))}
    skipped = dict.fromkeys(SKIP_REASONS, 0)

    starts = np.arange(0, n - horizon, stride) if n > horizon else np.zeros(0, dtype=int)
    if starts.size == 0:
        no_windows = {label: dict.fromkeys(SKIP_REASONS, 0) for label in labels}
        empty = dict.fromkeys(labels, 0)
        return WindowSplit({}, skipped, 0, float(dt), horizon, samples, no_windows, empty)

    # Per-sample flags, then per-window reductions over samples s..s+H (H steps).
    with np.errstate(invalid="ignore"):
        sample_ok = np.isfinite(t) & np.all(np.isfinite(states), axis=1)
        input_ok = np.all(np.isfinite(inputs), axis=1)
        step_ok = np.abs(np.diff(t) - dt) <= dt_rel_tol * dt  # NaN -> False
        fast = states[:, V] >= v_min
    span = np.arange(horizon + 1)
    idx = starts[:, None] + span[None, :]  # (W, H+1)
    finite_w = sample_ok[idx].all(axis=1) & input_ok[idx[:, :-1]].all(axis=1)
    steps_w = step_ok[idx[:, :-1]].all(axis=1)
    code_w = codes[idx]
    same_w = (code_w == code_w[:, :1]).all(axis=1)
    known_w = code_w[:, 0] >= 0
    fast_w = fast[idx].all(axis=1)

    remaining = np.ones(starts.size, dtype=bool)
    skipped_by_context = {label: dict.fromkeys(SKIP_REASONS, 0) for label in labels}
    for reason, ok in zip(SKIP_REASONS, (finite_w, steps_w, same_w, known_w, fast_w), strict=True):
        bad = remaining & ~ok
        skipped[reason] = int(bad.sum())
        first = code_w[bad, 0]
        for c, count in zip(*np.unique(first[first >= 0], return_counts=True), strict=True):
            skipped_by_context[labels[c]][reason] = int(count)
        remaining &= ok

    half_width = int(round(x0_smoothing_s / dt))
    x0_all = _initial_states(states, starts, sample_ok, step_ok, codes, half_width)
    by_context: dict[Hashable, WindowDataset] = {}
    available: dict[Hashable, int] = {}
    for c, label in enumerate(labels):
        sel = np.flatnonzero(remaining & (code_w[:, 0] == c))
        available[label] = int(sel.size)
        if sel.size == 0:
            continue
        if max_windows is not None and sel.size > max_windows:
            sel = sel[np.linspace(0, sel.size - 1, int(max_windows)).round().astype(np.int64)]
        s = starts[sel]
        win = idx[sel]
        by_context[label] = WindowDataset(
            x0=x0_all[sel],
            U=inputs[win[:, :-1]],
            X=states[win[:, 1:]],
            dt=float(dt),
            start=s.copy(),
            t0=t[s].copy(),
        )
    return WindowSplit(
        by_context,
        skipped,
        int(starts.size),
        float(dt),
        horizon,
        samples,
        skipped_by_context,
        available,
    )


def windows_from_log(
    log: pd.DataFrame,
    context_column: str | None = None,
    *,
    horizon: int = DEFAULT_HORIZON,
    stride: int = DEFAULT_STRIDE,
    v_min: float = DEFAULT_V_MIN_MPS,
    dt: float | None = None,
    dt_rel_tol: float = DEFAULT_DT_REL_TOL,
    x0_smoothing_s: float = DEFAULT_X0_SMOOTHING_S,
    default_label: Hashable = "all",
    max_windows: int | None = DEFAULT_MAX_WINDOWS,
) -> WindowSplit:
    """Fitting windows from a drive log (the format of ``pcvfe_drake.runs.drivelog``).

    Args:
        log: table with columns t, sx, sy, delta, v, psi, psi_dot, beta, steer_rate, accel.
        context_column: column with the context of each row (e.g. ``"terrain"`` or
            ``"context"``); ``None``: the whole log is one context labelled ``default_label``.
        Other arguments: as :func:`build_windows`.
    """
    if not isinstance(log, pd.DataFrame):
        raise ValueError(f"log must be a pandas DataFrame, got {type(log).__name__}")
    needed = ("t", *STATE_COLUMNS, *INPUT_COLUMNS)
    missing = [c for c in needed if c not in log.columns]
    if missing:
        raise ValueError(
            f"drive log is missing column(s) {missing}; found {', '.join(map(str, log.columns))}"
        )
    if context_column is not None and context_column not in log.columns:
        raise ValueError(
            f"context column '{context_column}' is not in the drive log; "
            f"found {', '.join(map(str, log.columns))}"
        )

    def numeric(cols):
        try:
            return log[list(cols)].apply(pd.to_numeric).to_numpy(dtype=float)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"drive log columns {list(cols)} must be numeric: {exc}") from exc

    contexts = None if context_column is None else log[context_column].to_numpy()
    return build_windows(
        numeric(["t"])[:, 0],
        numeric(STATE_COLUMNS),
        numeric(INPUT_COLUMNS),
        contexts,
        horizon=horizon,
        stride=stride,
        v_min=v_min,
        dt=dt,
        dt_rel_tol=dt_rel_tol,
        x0_smoothing_s=x0_smoothing_s,
        default_label=default_label,
        max_windows=max_windows,
    )
