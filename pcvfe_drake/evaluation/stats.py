"""Means with confidence intervals over seeds, and paired differences per seed (no pydrake)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats as sps

LEVEL = 0.95
"""Confidence level of every interval in the report."""


@dataclass(frozen=True)
class Interval:
    """Mean of ``n`` values and its two-sided Student-t confidence interval [lo, hi]."""

    n: int
    mean: float
    lo: float
    hi: float

    @property
    def half_width(self) -> float:
        return (self.hi - self.lo) / 2.0


def mean_ci(values, level: float = LEVEL) -> Interval:
    """Mean and Student-t CI of the finite ``values`` (NaN bounds below 2 values; a zero-width
    interval when all values are equal)."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n == 0:
        return Interval(0, math.nan, math.nan, math.nan)
    m = float(x.mean())
    if n < 2:
        return Interval(1, m, math.nan, math.nan)
    sem = float(x.std(ddof=1)) / math.sqrt(n)
    h = float(sps.t.ppf(0.5 + level / 2.0, n - 1)) * sem
    return Interval(n, m, m - h, m + h)


def paired_differences(
    runs: pd.DataFrame, metric: str, reference: str, *, by: tuple[str, ...] = ("seed",)
) -> pd.DataFrame:
    """Per seed (``by`` columns), ``metric`` of every source minus the ``reference`` source's.

    ``runs`` has columns ``source``, ``metric`` and ``by``; the result has ``by``, ``source``
    and ``diff``, for the pairs where both values are finite (one scenario at a time).
    """
    keys = list(by)
    ref = runs[runs["source"] == reference][[*keys, metric]].rename(columns={metric: "_ref"})
    other = runs[runs["source"] != reference][[*keys, "source", metric]]
    merged = other.merge(ref, on=keys, how="inner")
    merged["diff"] = merged[metric].astype(float) - merged["_ref"].astype(float)
    merged = merged[np.isfinite(merged["diff"])]
    return merged[[*keys, "source", "diff"]].reset_index(drop=True)
