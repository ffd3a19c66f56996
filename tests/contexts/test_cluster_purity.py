"""A cluster holding a pocket of another terrain must not pass that terrain's frames."""

from __future__ import annotations

import numpy as np

from pcvfe_drake.contexts.clustering import NOISE, ClusteringParams, ContextClusterer
from pcvfe_drake.contexts.density_gate import GateIndex, detach_small_groups, grow_by_gate
from pcvfe_drake.contexts.feature_streams import synthetic_feature_stream

# The clustering settings the shipped scenarios use (3 s to form a context at 10 Hz).
PARAMS = ClusteringParams(min_cluster_duration_s=3.0, min_samples_duration_s=3.0)


def planted_cluster(rng: np.random.Generator, dim: int = 10):
    """One HDBSCAN cluster as the clusterer can receive it: 200 frames of terrain A, a pocket of
    9 frames of terrain B (fewer than a cluster) and 8 transition frames between them (kind
    "strip" the half nearer A, "strip_b" the half nearer B)."""
    a = np.zeros(dim)
    b = np.zeros(dim)
    b[0] = 1.0
    body = a + rng.normal(0.0, 0.05, (200, dim))
    pocket = b + rng.normal(0.0, 0.01, (9, dim))
    frac = np.linspace(0.0, 1.0, 10)[1:-1, None]
    chain = (1.0 - frac) * a + frac * b + rng.normal(0.0, 0.01, (8, dim))
    x = np.vstack([body, pocket, chain])
    kind = np.array(["a"] * 200 + ["b"] * 9 + ["strip"] * 4 + ["strip_b"] * 4)
    return x, kind, a, b


def test_pocket_and_strip_are_detached_and_the_body_kept():
    rng = np.random.default_rng(0)
    x, kind, _, _ = planted_cluster(rng)
    labels = np.zeros(x.shape[0], dtype=int)
    out = detach_small_groups(x, labels, np.ones(x.shape[0]), PARAMS)
    assert np.all(out[kind == "b"] == NOISE)
    assert np.all(out[kind == "strip_b"] == NOISE)
    assert np.mean(out[kind == "a"] == 0) >= 0.98


def test_a_cluster_with_a_foreign_pocket_no_longer_accepts_the_foreign_terrain():
    rng = np.random.default_rng(1)
    x, kind, a, b = planted_cluster(rng)
    labels = np.zeros(x.shape[0], dtype=int)
    dim = x.shape[1]
    new_b = b + rng.normal(0.0, 0.01, (50, dim))
    new_a = a + rng.normal(0.0, 0.05, (50, dim))
    # Every member as an exemplar: the pocket passes the gate (what the detachment prevents).
    whole = GateIndex(x, labels, PARAMS)
    assert np.mean(whole.labels(new_b) == 0) > 0.9
    out = detach_small_groups(x, labels, np.ones(x.shape[0]), PARAMS)
    kept = out >= 0
    index = GateIndex(x[kept], out[kept], PARAMS)
    assert np.all(index.labels(new_b) == NOISE)
    assert np.mean(index.labels(new_a) == 0) >= 0.9


def test_a_second_lobe_as_large_as_a_cluster_stays():
    # A cluster that HDBSCAN kept whole although two dense parts lie apart: the part not grown
    # from the densest core is as large as a cluster, so it stays (only smaller groups go).
    rng = np.random.default_rng(2)
    dim = 10
    far = np.zeros(dim)
    far[1] = 1.0
    x = np.vstack([rng.normal(0.0, 0.05, (120, dim)), far + rng.normal(0.0, 0.05, (60, dim))])
    labels = np.zeros(x.shape[0], dtype=int)
    out = detach_small_groups(x, labels, np.ones(x.shape[0]), PARAMS)
    assert np.mean(out == 0) >= 0.98


def test_growth_reaches_every_member_of_one_dense_blob():
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 0.05, (150, 8))
    sq = (x * x).sum(1)
    d2 = np.maximum(sq[:, None] - 2.0 * x @ x.T + sq[None, :], 0.0)
    np.fill_diagonal(d2, np.inf)
    seed = np.zeros(150, dtype=bool)
    seed[np.argsort(np.linalg.norm(x, axis=1))[:30]] = True
    grown = grow_by_gate(d2, seed, PARAMS, float(sq.max()))
    assert grown.mean() >= 0.98
    assert grown[seed].all()
    assert grow_by_gate(d2, seed, PARAMS, float(sq.max()), max_rounds=1).sum() < grown.sum()


def test_a_transition_into_a_new_terrain_does_not_pass_the_known_one():
    # One lap: terrains A and C for 20 s each, then 0.9 s of terrain B (never seen before), the
    # strips between them blending the two sides. The transition frames from C into B join C's
    # cluster; they must not carry C's gate over B.
    first = synthetic_feature_stream(
        n_laps=1, terrain_durations_s=(20.0, 20.0, 0.9), outlier_fraction=0.0, seed=3
    )
    # The same terrains (same seed, same number of terrains), now driven 10 s on B.
    later = synthetic_feature_stream(
        n_laps=1, terrain_durations_s=(20.0, 20.0, 10.0), outlier_fraction=0.0, seed=3
    )
    clusterer = ContextClusterer(PARAMS)
    for t, z in zip(first.t_s, first.z, strict=True):
        clusterer.assign(z, float(t))
    clusterer.recluster(float(first.t_s[-1]))
    on_b = later.z[later.label == 2][10:]  # frames the first drive never saw
    assert np.all(clusterer.predict(on_b) == NOISE)
    for terrain in (0, 1):
        assert np.mean(clusterer.predict(later.z[later.label == terrain]) >= 0) >= 0.95
