"""How long a context's samples wait before a published fit uses them: a histogram of waits
[s] from each sample's time to the publication of the first fit whose data hold it.

The waits are binned at the data rate and never stored one by one, so the statistic costs the
same on a lap and on a day of driving. A histogram is replaced, never changed in place: the
estimator's copies (Drake copies its state every step) share it.
"""

from __future__ import annotations

import math

import numpy as np

BIN_S = 0.01
"""Bin width [s] of the histogram (the data rate)."""
BINS = 3000
"""Bins of the histogram (the last one holds every longer wait)."""


def add_waits(counts: np.ndarray | None, waits_s: np.ndarray) -> np.ndarray:
    """A new histogram: ``counts`` (None: empty) plus the waits ``waits_s`` [s]."""
    bins = np.minimum((np.maximum(waits_s, 0.0) / BIN_S).astype(int), BINS - 1)
    new = np.bincount(bins, minlength=BINS)
    return new if counts is None else new + counts


def wait_quantiles(counts: np.ndarray | None) -> tuple[float, float, int]:
    """``(p50, p99, samples)`` of a histogram [s] (NaN quantiles when it is empty); a
    quantile is the upper edge of its bin."""
    total = 0 if counts is None else int(counts.sum())
    if not total:
        return math.nan, math.nan, 0
    cum = np.cumsum(counts)
    p50, p99 = (float((np.searchsorted(cum, q * total) + 1) * BIN_S) for q in (0.5, 0.99))
    return p50, p99, total


def newly_used(
    t: np.ndarray, previous_end_s: float, data_end_s: float, used: np.ndarray | None = None
) -> np.ndarray:
    """The times [s] of the samples ``t`` that a fit on the data up to ``data_end_s`` uses for
    the first time, the previous fit's data having ended at ``previous_end_s`` (NaN: none);
    ``used``: which of ``t`` the fit's windows hold (None: all). A sample no window holds (the
    end of a visit, shorter than a window's stride) reaches no estimate and is not among them."""
    keep = t <= data_end_s + 1e-9
    if math.isfinite(previous_end_s):
        keep &= t > previous_end_s
    return t[keep if used is None else keep & used]
