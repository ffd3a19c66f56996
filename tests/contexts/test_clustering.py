"""ContextClusterer on synthetic feature streams with a planted truth."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from sklearn.metrics import adjusted_rand_score

from pcvfe_drake.contexts.clustering import (
    NOISE,
    ClusteringParams,
    ContextClusterer,
    full_hdbscan_labels,
    match_centroids,
)
from pcvfe_drake.contexts.feature_streams import OUTLIER, TRANSITION, synthetic_feature_stream
from pcvfe_drake.contexts.metrics import adjusted_rand, context_metrics

LATE = 4  # label of the terrain that appears from the second lap on


def run_online(stream, params, period_s=10.0):
    """Feed a stream frame by frame, re-clustering every ``period_s``; ids and re-cluster times."""
    clusterer = ContextClusterer(params)
    ids = np.empty(stream.t_s.size, dtype=int)
    recluster_t = []
    next_t = period_s
    for i, (t, z) in enumerate(zip(stream.t_s, stream.z, strict=True)):
        ids[i] = clusterer.assign(z, float(t))
        if t >= next_t - 1e-9:
            clusterer.recluster(float(t))
            recluster_t.append(float(t))
            next_t += period_s
    return clusterer, ids, np.array(recluster_t)


@pytest.fixture(scope="module")
def drive():
    # Three laps of the four default terrains; a fifth terrain joins each lap from the second
    # lap on; 1 % outliers; slow light drift. ~3500 frames: the store (2000) is saturated.
    stream = synthetic_feature_stream(
        n_laps=3, late_terrain_from_lap=1, drift=0.3, drift_period_s=200.0, seed=3
    )
    params = ClusteringParams()
    clusterer, ids, recluster_t = run_online(stream, params)
    return stream, params, clusterer, ids, recluster_t


def terrain_id(stream, ids, label):
    own = ids[(stream.label == label) & (ids >= 0)]
    values, counts = np.unique(own, return_counts=True)
    return int(values[counts.argmax()])


def test_params_in_physical_units():
    p = ClusteringParams(frame_rate_hz=10.0, min_cluster_duration_s=5.0)
    assert p.min_cluster_size == 50
    assert p.min_samples == 50
    assert p.noise_capacity == 600
    assert ClusteringParams(frame_rate_hz=30.0).min_cluster_size == 150
    with pytest.raises(ValueError, match="frame_rate_hz"):
        ClusteringParams(frame_rate_hz=0.0)
    with pytest.raises(ValueError, match="gate_quantile"):
        ClusteringParams(gate_quantile=1.5)
    with pytest.raises(ValueError, match="max_stored"):
        ClusteringParams(max_stored=100)
    with pytest.raises(ValueError, match="persistence_epsilon"):
        ClusteringParams(persistence_epsilon=-1.0)


def test_match_centroids_algorithm_1():
    a, b, c = np.array([0.0, 0.0]), np.array([10.0, 0.0]), np.array([0.0, 10.0])
    prev = np.array([a, b])
    eps = np.array([1.0, 1.0])
    # New centroids: b moved a little, c is new, a moved a little.
    cur = np.array([b + 0.1, c, a - 0.2])
    np.testing.assert_array_equal(match_centroids(prev, eps, cur), [1, -1, 0])
    # Beyond epsilon: a fresh id.
    np.testing.assert_array_equal(match_centroids(prev, eps, np.array([a + 2.0])), [-1])
    # Two previous centroids claim one new centroid: the closer one keeps its id.
    prev2 = np.array([a, a + 0.5])
    np.testing.assert_array_equal(match_centroids(prev2, eps, np.array([a + 0.4])), [1])
    # A vanished previous centroid (no new one near it) stays unmatched.
    np.testing.assert_array_equal(match_centroids(prev, eps, np.array([b])), [1])
    assert match_centroids(np.zeros((0, 2)), np.zeros(0), cur).tolist() == [-1, -1, -1]


def test_ids_persist_across_reclusterings(drive):
    stream, _, clusterer, ids, _ = drive
    terrains = [0, 1, 2, 3, LATE]
    own = {k: terrain_id(stream, ids, k) for k in terrains}
    assert len(set(own.values())) == len(terrains), own
    # Every visit after the first re-clustering (and after the late terrain got its id) reports
    # its terrain's id (or, for a few frames, noise): no re-labelling between re-clusterings.
    first_id_t = {k: stream.t_s[(stream.label == k) & (ids == own[k])][0] for k in terrains}
    for k in terrains:
        later = (stream.label == k) & (stream.t_s > first_id_t[k] + 10.0)
        assert later.sum() > 100
        assert set(np.unique(ids[later])) <= {own[k], NOISE}, (k, np.unique(ids[later]))
        assert np.mean(ids[later] == own[k]) > 0.9
    table = clusterer.table()
    assert sorted(table.active_ids) == sorted(own.values())
    assert table.n_reclusterings == int(stream.t_s[-1] // 10.0)


def test_revisits_reidentified_within_a_few_frames(drive):
    stream, _, _, ids, _ = drive
    m = context_metrics(stream.t_s, stream.label, ids)
    assert m.n_revisits >= 8
    assert m.n_reid_missed == 0
    assert m.reid_latency_max_s <= 0.5  # 5 frames at 10 Hz
    # Once every terrain has a context (the last lap), the online ids match the truth.
    last_lap = stream.t_s > stream.t_s[-1] - 120.0
    assert adjusted_rand(stream.label, ids, mask=last_lap) > 0.9


def test_new_terrain_is_noise_then_gets_a_new_id(drive):
    stream, params, _, ids, recluster_t = drive
    late = np.flatnonzero(stream.label == LATE)
    start = stream.t_s[late[0]]
    first_visit = late[stream.t_s[late] < start + 25.0]
    known = {terrain_id(stream, ids, k) for k in range(4)}
    # Never forced into a known context.
    assert not np.isin(ids[late], list(known)).any()
    # Noise until it has min_cluster_size frames and a re-clustering ran.
    ready = start + params.min_cluster_size / params.frame_rate_hz
    first_recluster = recluster_t[recluster_t >= ready - 0.05][0]
    before = first_visit[stream.t_s[first_visit] <= first_recluster]
    assert np.all(ids[before] == NOISE)
    # A new id from the first frame after that re-clustering on.
    after = first_visit[stream.t_s[first_visit] > first_recluster]
    new_id = ids[after[0]]
    assert new_id >= 0 and new_id not in known
    assert np.mean(ids[after] == new_id) > 0.95


def test_noise_stays_noise(drive):
    stream, _, _, ids, _ = drive
    outliers = stream.label == OUTLIER
    assert outliers.sum() > 10
    assert np.mean(ids[outliers] == NOISE) >= 0.95
    # Transition frames are mixtures: many are noise, none is a context of its own.
    trans_ids = set(ids[stream.label == TRANSITION].tolist()) - {NOISE}
    assert trans_ids <= {terrain_id(stream, ids, k) for k in (0, 1, 2, 3, LATE)}


def test_store_is_bounded_and_table_consistent(drive):
    stream, params, clusterer, ids, _ = drive
    assert stream.t_s.size > params.max_stored
    assert clusterer.n_stored <= params.max_stored
    assert clusterer.n_frames == stream.t_s.size
    table = clusterer.table()
    terrain_of = {terrain_id(stream, ids, k): k for k in (0, 1, 2, 3, LATE)}
    for rec in table.records:
        frames = stream.t_s[ids == rec.context_id]
        # Re-clustering may add stored frames that were noise when they came: times can only
        # widen, and stay within the drive.
        assert 0.0 <= rec.first_seen_s <= frames[0] + 1e-9
        assert frames[-1] - 1e-9 <= rec.last_seen_s <= stream.t_s[-1]
        # Size counts the frames it stands for (assigned online, or absorbed when re-clustered):
        # about the number of frames taken on its terrain, less the drifting frames the gate
        # left as noise (on this machine's BLAS kernels one terrain keeps 0.846 of its frames;
        # the share moves by a few per cent with the floating-point path of the distances).
        on_terrain = np.sum(stream.label == terrain_of[rec.context_id])
        assert 0.8 * on_terrain <= rec.size <= 1.1 * on_terrain
        assert rec.centroid.shape == (stream.z.shape[1],)
    with pytest.raises(KeyError, match="99"):
        table.record(99)


def test_bounded_store_is_faithful_to_full_hdbscan(drive):
    # The store holds ~2000 of ~3500 frames; labels of all frames from the bounded model vs
    # HDBSCAN over all frames with the same parameters.
    stream, params, clusterer, _, _ = drive
    full = full_hdbscan_labels(stream.z, params)
    ours = clusterer.predict(stream.z)
    assert full.max() + 1 == 5
    assert adjusted_rand_score(full, ours) >= 0.95


def test_single_terrain_at_the_start_forms_one_context():
    stream = synthetic_feature_stream(n_laps=1, outlier_fraction=0.0, seed=1).head(150)
    clusterer = ContextClusterer()
    for t, z in zip(stream.t_s, stream.z, strict=True):
        assert clusterer.assign(z, t) == NOISE  # nothing known yet
    table = clusterer.recluster(15.0)
    assert table.active_ids == [0]
    assert table.records[0].size > 0.9 * 150
    assert np.mean(clusterer.predict(stream.z) == 0) > 0.9


def test_unseen_terrain_is_noise_and_copies_are_independent():
    stream = synthetic_feature_stream(n_laps=2, late_terrain_from_lap=5, seed=2)
    base = stream.label < 2  # terrains 0 and 1 only
    clusterer = ContextClusterer()
    for t, z in zip(stream.t_s[base], stream.z[base], strict=True):
        clusterer.assign(z, t)
    clusterer.recluster(100.0)
    assert len(clusterer.table().active_ids) == 2
    unseen = stream.z[stream.label == 2]
    assert np.mean(clusterer.predict(unseen) == NOISE) > 0.99
    # assign agrees with predict and a deep copy does not share state.
    twin = copy.deepcopy(clusterer)
    z0 = stream.z[stream.label == 0][0]
    assert twin.assign(z0, 200.0) == clusterer.predict(z0)[0] >= 0
    assert twin.n_frames == clusterer.n_frames + 1
    assert clusterer.table().record(0).last_seen_s < 200.0


def _rows(table) -> list[tuple]:
    return [
        (*tuple(r.centroid), r.size, r.first_seen_s, r.last_seen_s, r.active, r.radius)
        for r in table.records
    ]


def test_a_copy_goes_on_exactly_as_the_original_and_shares_nothing_written():
    """The clusterer's own ``__deepcopy__`` copies only what its methods write into (the
    feature store at its first write): a copy fed the same frames gives the same ids, tables
    and store as the original, and frames fed to one (through the store's reservoir draws and
    re-clusterings) leave the other as it was."""
    stream = synthetic_feature_stream(n_laps=2, late_terrain_from_lap=1, seed=5)
    params = ClusteringParams(max_stored=300)  # a full store: the reservoir draws at random
    clusterer = ContextClusterer(params)
    half = len(stream.t_s) // 2
    for i, (t, z) in enumerate(zip(stream.t_s[:half], stream.z[:half], strict=True)):
        clusterer.assign_frame(z, t)
        if i % 100 == 99:
            clusterer.recluster(t)
    twin = copy.deepcopy(clusterer)
    frozen = copy.deepcopy(clusterer)
    # the feature store is shared read-only until a copy writes a row into it
    assert twin._x is clusterer._x is frozen._x and not clusterer._x.flags.writeable
    snapshot = (frozen._x.copy(), frozen._label.copy(), _rows(frozen.table()))
    for i, (t, z) in enumerate(zip(stream.t_s[half:], stream.z[half:], strict=True)):
        assert twin.assign_frame(z, t) == clusterer.assign_frame(z, t)
        if i % 100 == 99:
            assert _rows(twin.recluster(t)) == _rows(clusterer.recluster(t))
    assert np.array_equal(twin._x, clusterer._x) and np.array_equal(twin._w, clusterer._w)
    assert twin._x is not clusterer._x and twin._x.flags.writeable
    assert _rows(twin.table()) == _rows(clusterer.table())
    assert np.array_equal(frozen._x, snapshot[0]) and np.array_equal(frozen._label, snapshot[1])
    assert _rows(frozen.table()) == snapshot[2] != _rows(clusterer.table())
    assert frozen.n_frames == half


def test_bad_input_is_reported():
    clusterer = ContextClusterer()
    clusterer.assign(np.zeros(5), 0.0)
    with pytest.raises(ValueError, match="z has 6 numbers"):
        clusterer.assign(np.zeros(6), 0.1)
    with pytest.raises(ValueError, match="t_s"):
        clusterer.assign(np.zeros(5), float("nan"))
    with pytest.raises(ValueError, match="1-D"):
        clusterer.assign(np.zeros((2, 5)), 0.1)
    # A corrupt frame is noise and is not stored.
    assert clusterer.assign(np.full(5, np.nan), 0.2) == NOISE
    assert clusterer.n_stored == 1
    assert clusterer.predict(np.full((2, 5), np.nan)).tolist() == [NOISE, NOISE]


def test_any_feature_dimension():
    stream = synthetic_feature_stream(n_laps=1, n_captions=5, outlier_fraction=0.0, seed=4)
    clusterer, ids, _ = run_online(stream, ClusteringParams())
    assert clusterer.dim == 8
    assert len(clusterer.table().active_ids) == 4
    m = context_metrics(stream.t_s, stream.label, ids)
    assert m.n_contexts == 4


def test_epsilon_decides_between_same_id_and_new_id():
    stream = synthetic_feature_stream(n_laps=1, terrain_durations_s=(12.0, 12.0), seed=6)
    tables = {}
    for name, eps in (("tiny", 1e-9), ("default", None)):
        clusterer = ContextClusterer(ClusteringParams(persistence_epsilon=eps))
        for t, z in zip(stream.t_s, stream.z, strict=True):
            clusterer.assign(z, t)
        clusterer.recluster(25.0)
        # The same data again, shifted by 1e-4 (far less than a cluster radius): centroids move by
        # much less than a cluster radius, but by more than the tiny epsilon.
        for t, z in zip(stream.t_s, stream.z, strict=True):
            clusterer.assign(z + 1e-4, t + 30.0)
        tables[name] = clusterer.recluster(55.0)
    # Default epsilon: the two terrains keep ids 0 and 1.
    assert tables["default"].ids == [0, 1] and tables["default"].active_ids == [0, 1]
    # Epsilon below the centroid shift: fresh ids 2 and 3; 0 and 1 stay in the table, inactive.
    tiny = tables["tiny"]
    assert tiny.ids == [0, 1, 2, 3] and tiny.active_ids == [2, 3]
    assert not tiny.record(0).active and tiny.record(0).size > 200
