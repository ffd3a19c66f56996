"""Metrics of discovered terrain contexts against the true terrain labels.

Every function takes plain arrays: ``t_s`` (N,) sample times [s], nondecreasing; ``true_labels``
(N,) the terrain under the car (str or int); ``pred_ids`` (N,) int context ids reported at those
times (-1 = noise / unknown). Samples whose true label is in ``excluded_labels`` (transition
strips, outliers; by default -1, -2, "transition", "outlier", "", None and NaN) or where ``mask``
is False are left out of the scores; they do not end a visit to a terrain.

Definitions:

* **ARI**: adjusted Rand index between true labels and predicted ids over the included samples,
  noise (-1) counted as one more predicted label (a method that calls everything noise scores 0).
* **contexts discovered**: distinct predicted ids >= 0 (over all samples).
* **noise fraction**: share of included samples reported as -1.
* **visit**: a maximal run of included samples with the same true label.
* **id of a terrain**: the majority predicted id (>= 0) over its included samples. For
  re-identification the majority is taken over the samples *before* the visit ("so far"), so the
  score is causal: a revisit is re-identified when the id the terrain had is reported again.
* **re-identification latency** of a revisit (a visit to a terrain that already had an id before
  it): time from the visit's first sample to the first sample of the visit reporting that id; inf
  if the visit ends first.
* **time to first id** of a terrain: time from its first sample to its first sample reporting its
  overall majority id (inf if it never gets an id), counted across visits.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Collection
from dataclasses import asdict, dataclass, field

import numpy as np
from sklearn.metrics import adjusted_rand_score

DEFAULT_EXCLUDED: tuple = (-1, -2, "transition", "outlier", "", None)
"""True-label values that mean 'no terrain to score' (transition strips, outliers, unknown)."""


@dataclass(frozen=True)
class Visit:
    """One visit to a terrain: its label and the index range [start, stop) of the samples."""

    label: object
    start: int
    stop: int


@dataclass
class ContextMetrics:
    """Summary of a context-discovery run (all times in seconds).

    Attributes:
        ari: adjusted Rand index over included samples.
        n_contexts: distinct predicted ids >= 0.
        noise_fraction: share of included samples reported as noise.
        n_included: included samples.
        reid_latencies_s: latency of each revisit, in time order (inf = not re-identified).
        reid_latency_median_s, reid_latency_max_s: over the revisits (nan if there were none).
        n_revisits, n_reid_missed: revisits, and those never re-identified.
        first_id_time_s: per terrain label (as str), time to its first id (inf = never).
    """

    ari: float
    n_contexts: int
    noise_fraction: float
    n_included: int
    reid_latencies_s: list[float] = field(default_factory=list)
    reid_latency_median_s: float = math.nan
    reid_latency_max_s: float = math.nan
    n_revisits: int = 0
    n_reid_missed: int = 0
    first_id_time_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain dict (inf and nan kept as floats; json.dumps writes them as Infinity/NaN)."""
        return asdict(self)


def _is_excluded(value: object, excluded: set) -> bool:
    if value is None:
        return True
    if isinstance(value, float | np.floating) and math.isnan(value):
        return True
    try:
        return value in excluded
    except TypeError:
        return False


def _check(
    t_s: np.ndarray, true_labels: np.ndarray, pred_ids: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.asarray(t_s, dtype=float).reshape(-1)
    labels = np.asarray(true_labels, dtype=object).reshape(-1)
    pred = np.asarray(pred_ids)
    if pred.ndim != 1:
        raise ValueError(f"pred_ids must be 1-D, got shape {pred.shape}")
    if not (t.size == labels.size == pred.size):
        raise ValueError(
            f"t_s, true_labels and pred_ids must have the same length, got {t.size}, "
            f"{labels.size}, {pred.size}"
        )
    if not np.isfinite(t).all():
        raise ValueError("t_s has non-finite values")
    if t.size > 1 and np.any(np.diff(t) < 0):
        i = int(np.flatnonzero(np.diff(t) < 0)[0])
        raise ValueError(f"t_s must be nondecreasing, but t_s[{i + 1}]={t[i + 1]} < {t[i]}")
    if pred.size and not np.issubdtype(pred.dtype, np.integer):
        if not np.all(np.isfinite(pred.astype(float))) or np.any(pred != np.round(pred)):
            raise ValueError("pred_ids must be integers (-1 = noise)")
    return t, labels, pred.astype(int)


def included_mask(
    true_labels: np.ndarray,
    *,
    excluded_labels: Collection = DEFAULT_EXCLUDED,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) bool: samples to score (label not excluded, and ``mask`` where given)."""
    labels = np.asarray(true_labels, dtype=object).reshape(-1)
    excluded = set(excluded_labels)
    keep = np.array([not _is_excluded(v, excluded) for v in labels], dtype=bool)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool).reshape(-1)
        if mask.size != keep.size:
            raise ValueError(f"mask has {mask.size} entries, true_labels {keep.size}")
        keep &= mask
    return keep


def adjusted_rand(
    true_labels: np.ndarray,
    pred_ids: np.ndarray,
    *,
    excluded_labels: Collection = DEFAULT_EXCLUDED,
    mask: np.ndarray | None = None,
) -> float:
    """Adjusted Rand index over the included samples (nan if none is included)."""
    keep = included_mask(true_labels, excluded_labels=excluded_labels, mask=mask)
    if not keep.any():
        return math.nan
    labels = np.asarray(true_labels, dtype=object).reshape(-1)[keep]
    pred = np.asarray(pred_ids).reshape(-1)[keep]
    return float(adjusted_rand_score([str(v) for v in labels], pred))


def n_contexts(pred_ids: np.ndarray) -> int:
    """Distinct context ids >= 0."""
    pred = np.asarray(pred_ids).reshape(-1)
    return int(np.unique(pred[pred >= 0]).size)


def noise_fraction(pred_ids: np.ndarray, include: np.ndarray | None = None) -> float:
    """Share of (included) samples with id -1 (nan if there are none)."""
    pred = np.asarray(pred_ids).reshape(-1)
    if include is not None:
        pred = pred[np.asarray(include, dtype=bool)]
    return float(np.mean(pred < 0)) if pred.size else math.nan


def terrain_visits(true_labels: np.ndarray, include: np.ndarray) -> list[Visit]:
    """Maximal runs of included samples with the same label (excluded samples are skipped)."""
    labels = np.asarray(true_labels, dtype=object).reshape(-1)
    visits: list[Visit] = []
    idx = np.flatnonzero(include)
    start = None
    # Each included sample beside the next one (-1 after the last); none included: no visits.
    for a, b in zip(idx, np.append(idx[1:], -1)[: idx.size], strict=True):
        if start is None:
            start = a
        if b < 0 or labels[b] != labels[a]:
            visits.append(Visit(label=labels[a], start=int(start), stop=int(a) + 1))
            start = None
    return visits


def _majority(ids: np.ndarray) -> int | None:
    ids = ids[ids >= 0]
    if ids.size == 0:
        return None
    values, counts = np.unique(ids, return_counts=True)
    return int(values[counts.argmax()])


def reidentification_latencies(
    t_s: np.ndarray,
    true_labels: np.ndarray,
    pred_ids: np.ndarray,
    *,
    excluded_labels: Collection = DEFAULT_EXCLUDED,
    mask: np.ndarray | None = None,
) -> list[tuple[object, float, float]]:
    """Re-identification latency of every revisit: (label, visit start [s], latency [s]).

    A revisit is a visit to a terrain whose earlier included samples already had an id; its id is
    the majority of those earlier ids. Latency is inf if the visit ends before the id is reported.
    """
    t, labels, pred = _check(t_s, true_labels, pred_ids)
    keep = included_mask(labels, excluded_labels=excluded_labels, mask=mask)
    history: dict[object, list[np.ndarray]] = {}
    out: list[tuple[object, float, float]] = []
    for v in terrain_visits(labels, keep):
        rows = np.arange(v.start, v.stop)[keep[v.start : v.stop]]
        past = history.setdefault(v.label, [])
        own = _majority(np.concatenate(past)) if past else None
        if own is not None:
            hits = rows[pred[rows] == own]
            latency = float(t[hits[0]] - t[rows[0]]) if hits.size else math.inf
            out.append((v.label, float(t[rows[0]]), latency))
        past.append(pred[rows])
    return out


def first_id_times(
    t_s: np.ndarray,
    true_labels: np.ndarray,
    pred_ids: np.ndarray,
    *,
    excluded_labels: Collection = DEFAULT_EXCLUDED,
    mask: np.ndarray | None = None,
) -> dict[str, float]:
    """Per terrain (label as str): time from its first sample to its first sample reporting its
    overall majority id [s]; inf if it never gets an id."""
    t, labels, pred = _check(t_s, true_labels, pred_ids)
    keep = included_mask(labels, excluded_labels=excluded_labels, mask=mask)
    out: dict[str, float] = {}
    for label in Counter(labels[keep].tolist()):
        rows = np.flatnonzero(keep & (labels == label))
        own = _majority(pred[rows])
        if own is None:
            out[str(label)] = math.inf
            continue
        first_hit = rows[pred[rows] == own][0]
        out[str(label)] = float(t[first_hit] - t[rows[0]])
    return out


def context_metrics(
    t_s: np.ndarray,
    true_labels: np.ndarray,
    pred_ids: np.ndarray,
    *,
    excluded_labels: Collection = DEFAULT_EXCLUDED,
    mask: np.ndarray | None = None,
) -> ContextMetrics:
    """All metrics of the module in one :class:`ContextMetrics`."""
    t, labels, pred = _check(t_s, true_labels, pred_ids)
    keep = included_mask(labels, excluded_labels=excluded_labels, mask=mask)
    reid = reidentification_latencies(t, labels, pred, excluded_labels=excluded_labels, mask=mask)
    lat = np.array([r[2] for r in reid], dtype=float)
    return ContextMetrics(
        ari=adjusted_rand(labels, pred, excluded_labels=excluded_labels, mask=mask),
        n_contexts=n_contexts(pred),
        noise_fraction=noise_fraction(pred, keep),
        n_included=int(keep.sum()),
        reid_latencies_s=[float(x) for x in lat],
        reid_latency_median_s=float(np.median(lat)) if lat.size else math.nan,
        reid_latency_max_s=float(lat.max()) if lat.size else math.nan,
        n_revisits=int(lat.size),
        n_reid_missed=int(np.isinf(lat).sum()),
        first_id_time_s=first_id_times(t, labels, pred, excluded_labels=excluded_labels, mask=mask),
    )
