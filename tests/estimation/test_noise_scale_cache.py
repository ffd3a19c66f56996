"""The noise scales cache (``models.data.NoiseScaleCache``) gives the uncached numbers bit for
bit, on a buffer that grows, drops its oldest samples, has a time gap, and turns non-finite."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from pcvfe_drake.estimation.effect_fit import drive_data_from_arrays
from pcvfe_drake.models import data as D
from pcvfe_drake.models.data import NoiseScaleCache, robust_noise_sigmas

DT = 0.01


def _bits(a) -> np.ndarray:
    return np.asarray(a, dtype=float).view(np.int64)


def _buffer(n: int, seed: int = 0):
    """A smooth drive with sensor noise, the heading wrapping past pi, quantised steering
    (ties in the medians)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    x = np.column_stack(
        [
            np.cumsum(np.full(n, 0.05)),
            np.sin(0.2 * t),
            np.round(0.1 * np.sin(0.5 * t), 3),
            5.0 + 0.5 * np.sin(0.1 * t),
            np.angle(np.exp(1j * 0.4 * t)),
            0.4 + 0.05 * np.sin(0.3 * t),
            0.01 * np.sin(0.7 * t),
        ]
    )
    x += 1e-3 * rng.standard_normal(x.shape)
    u = np.column_stack([0.05 * np.cos(0.5 * t), 0.1 * np.sin(0.2 * t)])
    return t, x, u


@pytest.mark.parametrize("m", [1, 2, 3, 4, 5, 6, 7, 40, 41, 1000, 1001])
def test_mads_from_sorted_rows_equal_numpys(m):
    rng = np.random.default_rng(m)
    values = np.round(rng.standard_normal((8, m)), 1)  # many ties
    values[5] = 0.0
    values[6] = rng.standard_normal(m)  # no ties
    values[7] = np.round(rng.exponential(size=m), 0)  # one-sided, few distinct values
    values.sort(axis=1)
    expected = np.median(np.abs(values - np.median(values, axis=1, keepdims=True)), axis=1)
    np.testing.assert_array_equal(_bits(D._sorted_mads(values)), _bits(expected))


@pytest.mark.parametrize("gone, new", [(0, 0), (3, 0), (0, 4), (5, 7), (20, 20)])
def test_merged_rows_equal_the_sorted_multiset(gone, new):
    rng = np.random.default_rng(gone + 10 * new)
    rows = np.round(rng.standard_normal((7, 30)), 1)  # many ties, zeros among them
    rows.sort(axis=1)
    take = np.stack([rng.choice(30, gone, replace=False) for _ in range(7)])
    dropped = np.take_along_axis(rows, take, axis=1)
    added = np.round(rng.standard_normal((7, new)), 1)
    got = D._merge_differences(rows, dropped, added)
    keep = np.ones(rows.shape, bool)
    np.put_along_axis(keep, take, False, axis=1)
    expected = np.sort(np.hstack([rows[keep].reshape(7, 30 - gone), added]), axis=1)
    np.testing.assert_array_equal(got, expected)


def test_cache_equals_the_uncached_scales_on_a_buffer_that_grows_drops_and_turns_nan(
    monkeypatch,
):
    merged = []
    merge = D._merge_differences
    monkeypatch.setattr(D, "_merge_differences", lambda *a: merged.append(1) or merge(*a))
    t, x, _ = _buffer(1500)
    cache = NoiseScaleCache()
    calls = [(0, 60), (0, 160), (0, 400), (0, 400), (30, 520), (150, 600), (150, 601)]
    calls += [(700, 900), (710, 1000), (710, 1000)]  # a jump (no overlap), then continued
    calls += [(720, 1100), (800, 1100)]  # only drops, only grows
    for lo, hi in calls:
        got = cache.sigmas(t[lo:hi], x[lo:hi], 10)
        np.testing.assert_array_equal(_bits(got), _bits(robust_noise_sigmas(x[lo:hi], 10)))
    changed = x.copy()
    changed[900, 3] += 1e-9  # a kept sample changed: recomputed, not merged
    got = cache.sigmas(t[850:1150], changed[850:1150], 10)
    np.testing.assert_array_equal(_bits(got), _bits(robust_noise_sigmas(changed[850:1150], 10)))
    bad = x[850:1200].copy()
    bad[10, 1] = np.nan
    got = cache.sigmas(t[850:1200], bad, 10)
    np.testing.assert_array_equal(_bits(got), _bits(robust_noise_sigmas(bad, 10)))
    for lo, hi in [(860, 1210), (870, 1300)]:  # after the NaN: from scratch, then merged
        got = cache.sigmas(t[lo:hi], x[lo:hi], 10)
        np.testing.assert_array_equal(_bits(got), _bits(robust_noise_sigmas(x[lo:hi], 10)))
    short = cache.sigmas(t[:30], x[:30], 10)  # too short for all strides: the plain form
    np.testing.assert_array_equal(_bits(short), _bits(robust_noise_sigmas(x[:30], 10)))
    assert len(merged) >= 8 * 10  # the continued calls merged (10 strides each)


def test_a_copy_sharing_the_cache_still_gets_its_own_buffers_numbers():
    t, x, _ = _buffer(900, seed=3)
    cache = NoiseScaleCache()
    cache.sigmas(t[:500], x[:500], 10)
    other = copy.copy(cache)  # shares the last state, as the estimator's copies do
    a = other.sigmas(t[100:700], x[100:700], 10)
    b = cache.sigmas(t[50:600], x[50:600], 10)
    np.testing.assert_array_equal(_bits(a), _bits(robust_noise_sigmas(x[100:700], 10)))
    np.testing.assert_array_equal(_bits(b), _bits(robust_noise_sigmas(x[50:600], 10)))


def test_drive_data_with_the_cache_equals_without_on_a_buffer_with_a_gap():
    t, x, u = _buffer(3000, seed=5)
    keep = np.ones(t.size, bool)
    keep[1200:1350] = False  # a time gap: the longest gap-free segment changes over the calls
    t, x, u = t[keep], x[keep], u[keep]
    cache = NoiseScaleCache()
    for lo, hi in [(0, 800), (0, 1100), (0, 1300), (100, 1400), (200, 1500), (900, 2600)]:
        plain = drive_data_from_arrays(t[lo:hi], x[lo:hi], u[lo:hi], "buffer")
        cached = drive_data_from_arrays(t[lo:hi], x[lo:hi], u[lo:hi], "buffer", cache)
        for field in ("t", "x", "u", "x0", "sigma", "context"):
            np.testing.assert_array_equal(getattr(cached, field), getattr(plain, field))
        assert _bits(cached.sigma).tolist() == _bits(plain.sigma).tolist()
        assert cached.dt == plain.dt and cached.x0_delta_sigma == plain.x0_delta_sigma
