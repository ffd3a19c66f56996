"""The noise scales cache's work on sorted rows, compiled (numba).

``NoiseScaleCache`` keeps, per stride, the 4th differences of each state column sorted; at every
refit of a context it removes the differences of the samples that left the buffer, merges in
those of the new samples, and reads each row's median absolute deviation: 10 strides x 7 columns
x a 60 s buffer at every refit, where whole-row numpy passes would touch every value several
times. Per row:

* :func:`merge_rows`: the places of the values gone and of the new ones by bisection, and the
  runs between them copied whole;
* :func:`sorted_mads`: the deviations from a sorted row's median fall toward the median and
  rise after it, so read outward from the median they are two sorted runs, and the median
  absolute deviation, their middle element (the mean of the two middle ones for an even
  count, added and halved as ``np.median`` does), is found by bisection.

Both give ``models.data``'s numbers to the bit (``tests/estimation/test_noise_scale_cache.py``):
a multiset's order statistics do not depend on where equal values sit, and the deviations are
the same expressions (``abs(v - median)``). One module, because numba's disk cache keys a
compiled function on its own file.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def merge_rows(values: np.ndarray, gone: np.ndarray, new: np.ndarray) -> np.ndarray:
    """The sorted rows of ``values`` (k, m) without the values ``gone`` (k, g; each present,
    any order) and with the values ``new`` (k, a; any order), sorted (k, m - g + a)."""
    k, m = values.shape
    g, a = gone.shape[1], new.shape[1]
    out = np.empty((k, m - g + a))
    at_gone = np.empty(g, dtype=np.int64)
    for r in range(k):
        row = values[r]
        drop = np.sort(gone[r])
        add = np.sort(new[r])
        after = 0
        for j in range(g):  # each value gone at its own place (equal ones at the next places)
            at_gone[j] = after + np.searchsorted(row[after:], drop[j])
            after = at_gone[j] + 1
        at_new = np.searchsorted(row, add)  # each new value before its equals in the row
        i = 0  # read position in the row
        o = 0
        j = 0
        q = 0
        while j < g or q < a:
            next_gone = at_gone[j] if j < g else m
            next_new = at_new[q] if q < a else m
            p = min(next_gone, next_new)
            out[r, o : o + p - i] = row[i:p]
            o += p - i
            i = p
            if next_new <= next_gone:
                out[r, o] = add[q]
                o += 1
                q += 1
            else:
                i += 1  # the value gone
                j += 1
        out[r, o:] = row[i:]
    return out


@numba.njit(cache=True)
def _kth_deviation(row: np.ndarray, med: float, h: int, k: int) -> float:
    """The ``k``-th smallest (1-based) of ``abs(row - med)`` over a sorted ``row`` whose first
    ``h`` values lie at or below ``med`` and the rest at or above it: the ``k``-th of two sorted
    runs, ``L`` (the deviations read from ``h - 1`` down to 0) and ``R`` (from ``h`` up), by
    bisection on how many of the ``k`` come from ``L``."""
    m = row.size
    n_left, n_right = h, m - h
    lo, hi = max(0, k - n_right), min(k, n_left)
    while lo < hi:  # the least i with L[i] >= R[k - i - 1] (i from L, k - i from R)
        i = (lo + hi) // 2
        if abs(row[h - 1 - i] - med) < abs(row[h + k - i - 1] - med):
            lo = i + 1
        else:
            hi = i
    below = abs(row[h - lo] - med) if lo > 0 else -np.inf  # L[lo - 1]
    above = abs(row[h + k - lo - 1] - med) if k - lo > 0 else -np.inf  # R[k - lo - 1]
    return max(below, above)


@numba.njit(cache=True)
def sorted_mads(values: np.ndarray) -> np.ndarray:
    """``median(abs(v - median(v)))`` of each sorted, finite row ``v`` of ``values`` (k, m)."""
    k, m = values.shape
    h = m // 2
    out = np.empty(k)
    for r in range(k):
        row = values[r]
        if m % 2:
            out[r] = _kth_deviation(row, row[h], h, h + 1)
        else:
            med = (row[h - 1] + row[h]) / 2
            out[r] = (_kth_deviation(row, med, h, h) + _kth_deviation(row, med, h, h + 1)) / 2
    return out


def load() -> None:
    """Compile or load both functions now (numba's disk cache), not in a loop's first refit."""
    row = np.array([[0.0, 1.0, 2.0]])
    sorted_mads(merge_rows(row, row[:, :1], row[:, :1]))
