"""A rejected frame continuing the visit of the context before it
(ClusteringParams.continuation_gate_scale), and the one-terrain re-clustering when
min_samples is larger than min_cluster_size."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.contexts.clustering import NOISE, ClusteringParams, ContextClusterer

A = np.array([1.0, 0.0, 0.0])
B = np.array([0.0, 1.0, 0.0])
FAR = np.array([0.0, 0.0, 1.0])


def two_terrains(scale: float | None) -> tuple[ContextClusterer, int, int]:
    """10 s on terrain A, 10 s on B (10 Hz, spread 0.01), re-clustered; ids of A and B."""
    clusterer, a, b = two_terrains_into(
        ContextClusterer(ClusteringParams(frame_rate_hz=10.0, continuation_gate_scale=scale))
    )
    assert a >= 0 and b >= 0 and a != b
    return clusterer, a, b


def shifted(clusterer: ContextClusterer, centre: np.ndarray, away: np.ndarray) -> np.ndarray:
    """The first point from ``centre`` toward ``away`` that the outlier gate rejects."""
    for m in np.linspace(0.0, 0.5, 501):
        z = centre + m * (away - centre) / np.linalg.norm(away - centre)
        if clusterer.predict(z)[0] == NOISE:
            return z
    raise AssertionError("no rejected point found")


def test_params_validate_the_scale():
    assert ClusteringParams().continuation_gate_scale is None  # off: the paper's design
    ClusteringParams(continuation_gate_scale=1.0)
    for bad in (0.5, 0.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="continuation_gate_scale"):
            ClusteringParams(continuation_gate_scale=bad)


def test_a_frame_just_outside_the_gate_continues_the_visit():
    clusterer, a, _ = two_terrains(3.0)
    z = shifted(clusterer, A, FAR)
    assert clusterer.assign(A, 20.0) == a
    n_a = clusterer.table().records[a].size
    stored_noise = int(np.sum(clusterer.stored().labels == NOISE))
    for k in range(5):  # a run of such frames keeps the id: the reference is the stored members
        assert clusterer.assign(z, 20.1 + 0.1 * k) == a
    assert clusterer.continued_frames == 5
    # stored as noise, the context unchanged: re-clustering decides as always
    assert clusterer.table().records[a].size == n_a
    assert int(np.sum(clusterer.stored().labels == NOISE)) == stored_noise + 5
    # a frame far from every context ends the visit, and the near frame after it is noise
    assert clusterer.assign(FAR, 21.0) == NOISE
    assert clusterer.assign(z, 21.1) == NOISE


def test_off_and_after_noise_the_frame_stays_noise():
    off, a, _ = two_terrains(None)
    z = shifted(off, A, FAR)
    assert off.assign(A, 20.0) == a
    assert off.assign(z, 20.1) == NOISE
    assert off.continued_frames == 0
    on, a, _ = two_terrains(3.0)
    assert on.assign(FAR, 20.0) == NOISE  # no visit to continue
    assert on.assign(shifted(on, A, FAR), 20.1) == NOISE


def test_a_frame_far_beyond_the_widened_gate_or_nearer_another_context_is_noise():
    clusterer, a, b = two_terrains(1.5)
    assert clusterer.assign(A, 20.0) == a
    assert clusterer.assign(A + 0.3 * (FAR - A), 20.1) == NOISE  # far beyond 1.5 gates
    # nearest to B's members (though B's gate rejects it): not A's visit
    assert clusterer.assign(A, 20.2) == a
    z = shifted(clusterer, B, A)
    assert np.linalg.norm(z - B) < np.linalg.norm(z - A)
    assert clusterer.assign(z, 20.3) == NOISE
    assert clusterer.assign(B, 20.4) == b


def test_one_terrain_with_min_samples_above_min_cluster_size():
    # 34 frames >= min_cluster_size (30) but fewer than min_samples (50) + 1: no cluster yet,
    # no error (HDBSCAN refuses min_samples above the number of points)
    params = ClusteringParams(frame_rate_hz=10.0, min_cluster_duration_s=3.0)
    assert params.min_samples > params.min_cluster_size
    clusterer = ContextClusterer(params)
    rng = np.random.default_rng(1)
    for k in range(34):
        clusterer.assign(A + 0.01 * rng.standard_normal(3), 0.1 * k)
    assert clusterer.recluster(3.4).records == []
    for k in range(34, 80):
        clusterer.assign(A + 0.01 * rng.standard_normal(3), 0.1 * k)
    assert len(clusterer.recluster(8.0).records) == 1


def test_a_hold_keeps_the_visit_open_through_frames_beyond_the_widened_gate():
    """``continuation_hold_s``: a frame beyond the widened gate but nearest to the visit's
    context is noise and leaves the visit open for the hold (brick's blurred last frames lay
    1.1-3.3 gates away, one at 3.08-3.09 ended the visit and the 1.1-2.8 gate frames after it
    stayed noise); far from it, nearer another context, or after the hold, it ends the visit."""
    beyond = A + 0.3 * (FAR - A)  # nearest to A's members, beyond 3 gates

    def held(hold):
        clusterer = ContextClusterer(
            ClusteringParams(frame_rate_hz=10.0, continuation_gate_scale=3.0, **hold)
        )
        return two_terrains_into(clusterer)

    off, a, _ = held({})
    z = shifted(off, A, FAR)
    assert off.assign(A, 20.0) == a
    assert off.assign(beyond, 20.1) == NOISE
    assert off.assign(z, 20.2) == NOISE  # without the hold the visit ended
    on, a, b = held({"continuation_hold_s": 1.0})
    assert on.assign(A, 20.0) == a
    assert on.assign(beyond, 20.1) == NOISE  # noise itself
    assert on.assign(z, 20.2) == a  # the visit goes on
    for k in range(11):  # beyond for longer than the hold: the visit ends
        assert on.assign(beyond, 20.3 + 0.1 * k) == NOISE
    assert on.assign(z, 21.5) == NOISE
    assert on.assign(A, 22.0) == a
    assert on.assign(shifted(on, B, A), 22.1) == NOISE  # nearest to B: ends A's visit
    assert on.assign(z, 22.2) == NOISE
    ClusteringParams(continuation_gate_scale=3.0, continuation_hold_s=0.0)
    for bad in (
        {"continuation_hold_s": 1.0},
        {"continuation_gate_scale": 3.0, "continuation_hold_s": -1.0},
    ):
        with pytest.raises(ValueError, match="continuation_hold_s"):
            ClusteringParams(**bad)


def two_terrains_into(clusterer: ContextClusterer) -> tuple[ContextClusterer, int, int]:
    """10 s on terrain A, 10 s on B (10 Hz, spread 0.01) into ``clusterer``, re-clustered; ids
    of A and B."""
    rng = np.random.default_rng(4)
    t = 0.0
    for centre in (A, B):
        for _ in range(100):
            clusterer.assign(centre + 0.01 * rng.standard_normal(3), t)
            t += 0.1
    clusterer.recluster(t)
    ids = clusterer.predict(np.array([A, B]))
    return clusterer, int(ids[0]), int(ids[1])
