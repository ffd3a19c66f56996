"""Novelty-triggered re-clustering (ClusteringParams.novelty_window_s): when it fires, its rate
limit, and what it changes against the paper's periodic re-clustering alone."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.contexts.clustering import ClusteringParams, ContextClusterer
from pcvfe_drake.contexts.feature_streams import synthetic_feature_stream
from pcvfe_drake.contexts.metrics import context_metrics


def run(stream, params, period_s=10.0):
    """Frame by frame with the periodic re-clustering and, if configured, the trigger (as the
    ContextClustering system does); ids, periodic and triggered re-clustering times."""
    clusterer = ContextClusterer(params)
    ids = np.empty(stream.t_s.size, dtype=int)
    periodic, triggered = [], []
    next_t = period_s
    for i, (t, z) in enumerate(zip(stream.t_s, stream.z, strict=True)):
        if t >= next_t - 1e-9:
            ids[i] = clusterer.assign(z, float(t))
            clusterer.recluster(float(t))
            periodic.append(float(t))
            next_t += period_s
            continue
        ids[i], kept = clusterer.assign_frame(z, float(t))
        if kept:
            triggered.append(float(t))
    return clusterer, ids, np.array(periodic), np.array(triggered)


def first_id_after_entry(stream, ids, label):
    """Seconds from each entry into terrain ``label`` until a frame of it has that visit's id."""
    out = []
    # Outlier and transition frames (negative labels) belong to the terrain before them.
    filled = stream.label.copy()
    for i in range(1, filled.size):
        if filled[i] < 0:
            filled[i] = filled[i - 1]
    on = filled == label
    starts = np.flatnonzero(on & ~np.r_[False, on[:-1]])
    for s in starts:
        end = s + np.argmax(~on[s:]) if not on[s:].all() else on.size
        visit = ids[s:end]
        named = np.flatnonzero((visit >= 0) & (stream.label[s:end] == label))
        out.append(stream.t_s[s + named[0]] - stream.t_s[s] if named.size else np.inf)
    return np.array(out)


def test_params_validate_the_trigger():
    assert ClusteringParams().novelty_window_s is None  # off by default: the paper's design
    assert ClusteringParams().novelty_frames is None
    p = ClusteringParams(frame_rate_hz=10.0, novelty_window_s=6.0, novelty_fraction=0.75)
    assert p.novelty_frames == 45
    assert ClusteringParams(novelty_window_s=6.0).novelty_frames == 48  # no rounding up
    with pytest.raises(ValueError, match="novelty_window_s"):
        ClusteringParams(novelty_window_s=2.0)  # shorter than min_cluster_duration_s (5 s)
    with pytest.raises(ValueError, match="novelty_fraction"):
        ClusteringParams(novelty_window_s=5.0, novelty_fraction=0.0)
    with pytest.raises(ValueError, match="novelty_min_interval_s"):
        ClusteringParams(novelty_window_s=5.0, novelty_min_interval_s=0.0)


def test_due_after_a_window_of_noise_and_rate_limited():
    params = ClusteringParams(frame_rate_hz=10.0, novelty_window_s=5.0, novelty_fraction=0.8)
    clusterer = ContextClusterer(params)
    rng = np.random.default_rng(0)
    t = 0.0
    for k in range(39):  # 3.9 s of frames of one terrain: 39 noise frames < 40
        t = 0.1 * k
        clusterer.assign(np.array([1.0, 0.0, 0.0]) + 0.01 * rng.standard_normal(3), t)
    assert not clusterer.novelty_due(t)
    t += 0.1
    clusterer.assign(np.array([1.0, 0.0, 0.0]) + 0.01 * rng.standard_normal(3), t)
    assert clusterer.recent_noise_frames(t, 5.0) == 40
    assert clusterer.novelty_due(t)
    # The off switch: the same store, no trigger.
    off = ContextClusterer(ClusteringParams(frame_rate_hz=10.0))
    assert not off.novelty_due(t)
    # Too few frames for a cluster (50): the attempt names nothing and changes nothing.
    before = clusterer.frame_labels()
    assert not clusterer.recluster_if_novel(t)
    assert clusterer.table().active_ids == [] and clusterer.table().n_reclusterings == 0
    assert clusterer.frame_labels().version == before.version
    assert clusterer.novelty_counts == (1, 0)
    t += 0.5
    clusterer.assign(np.array([1.0, 0.0, 0.0]), t)
    assert not clusterer.novelty_due(t)  # within novelty_min_interval_s (1 s) of the last one
    assert clusterer.novelty_due(t + 0.6)
    for k in range(1, 20):  # 2 s more of the terrain: now dense enough to stand on its own
        clusterer.assign(np.array([1.0, 0.0, 0.0]) + 0.01 * rng.standard_normal(3), t + 0.1 * k)
    assert clusterer.recluster_if_novel(t + 1.9)
    assert clusterer.table().active_ids == [0] and clusterer.table().n_reclusterings == 1
    assert clusterer.novelty_counts == (2, 1)
    assert clusterer.assign(np.array([1.0, 0.0, 0.0]), t + 2.0) == 0


def test_trigger_cuts_the_new_terrain_latency_and_keeps_ids():
    # Two laps over four terrains of 20-30 s: every terrain is new on the first lap.
    stream = synthetic_feature_stream(n_laps=2, outlier_fraction=0.01, seed=11)
    base = ClusteringParams(frame_rate_hz=10.0)
    fast = ClusteringParams(frame_rate_hz=10.0, novelty_window_s=6.0)
    _, ids0, periodic0, trig0 = run(stream, base)
    clusterer, ids1, periodic1, trig1 = run(stream, fast)
    assert trig0.size == 0 and trig1.size > 0
    np.testing.assert_array_equal(periodic0, periodic1)  # the period stays the base
    first_visits = []
    for label in range(4):
        lat0 = first_id_after_entry(stream, ids0, label)
        lat1 = first_id_after_entry(stream, ids1, label)
        first_visits.append((lat0[0], lat1[0]))
        assert lat1[0] <= lat0[0]  # never later than the period alone
        assert lat1[1] <= 0.5  # second lap: re-identified at once (persistent id)
    # Terrains 1-3 entered at a random phase of the 10 s period: the periodic path waits longer
    # on average (the start terrain is named at 10 s by the period, earlier by the trigger).
    mean0 = np.mean([a for a, _ in first_visits])
    mean1 = np.mean([b for _, b in first_visits])
    assert mean1 < mean0 - 2.0
    assert sum(b <= 8.0 for _, b in first_visits) >= 3  # ~5-6 s of frames, plus retries
    # No frame more in a wrong context than with the period alone (a triggered clustering
    # that merged a new terrain's first frames into a neighbour is not kept), a better score.
    for label in range(4):
        wrong = []
        for ids in (ids0, ids1):
            on = (stream.label == label) & (ids >= 0)
            _, counts = np.unique(ids[on], return_counts=True)
            wrong.append(counts.sum() - counts.max())
        assert wrong[1] <= wrong[0]
    m0 = context_metrics(stream.t_s, stream.label, ids0, excluded_labels=(-1, -2))
    m1 = context_metrics(stream.t_s, stream.label, ids1, excluded_labels=(-1, -2))
    assert m1.n_contexts == 4
    assert m1.ari > m0.ari
    # Bounded: attempts at most one per novelty_min_interval_s while a terrain is noise; kept
    # ones at most one per new terrain here.
    tries, kept = clusterer.novelty_counts
    assert kept == trig1.size <= 4
    assert tries <= 4 * 6
    assert np.all(np.diff(np.sort(np.r_[periodic1, trig1])) > 0)
    assert clusterer.n_stored <= fast.max_stored
