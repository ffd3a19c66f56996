"""A cluster holding a pocket of another terrain must not pass that terrain's frames, and a
cluster without one keeps its gate."""

from __future__ import annotations

import numpy as np

from pcvfe_drake.contexts import density_gate
from pcvfe_drake.contexts.clustering import NOISE, ClusteringParams
from pcvfe_drake.contexts.density_gate import GateIndex, detach_small_groups

# The clustering settings the shipped scenarios use (3 s to form a context at 10 Hz).
PARAMS = ClusteringParams(min_cluster_duration_s=3.0, min_samples_duration_s=3.0)
DIM = 10


def body(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    """Frames of one terrain: a dense blob at the origin."""
    return rng.normal(0.0, 0.05, (n, DIM))


def sparse_pocket(rng: np.random.Generator, n: int = 12, spacing: float = 0.3) -> np.ndarray:
    """A few frames of another terrain seen at speed: a sparse line leading away from the body
    (its members' own k-th-neighbour distances, about twice the spacing, are what widens the
    gate of a cluster holding them)."""
    start = 0.6
    pts = np.zeros((n, DIM))
    pts[:, 0] = start + spacing * np.arange(n)
    return pts + rng.normal(0.0, 0.01, (n, DIM))


def pocket_frames(rng: np.random.Generator, pocket: np.ndarray, n: int = 50) -> np.ndarray:
    """New frames of the pocket's terrain: near its members."""
    return pocket[rng.integers(0, pocket.shape[0], n)] + rng.normal(0.0, 0.02, (n, DIM))


def test_a_sparse_pocket_widens_the_gate_enough_to_stay_linked_and_pass_its_terrain():
    # What the pocket rule is for: judged by the gate it widens itself, the pocket is linked to
    # the body (the component cut alone keeps it) and the cluster's gate passes its terrain.
    rng = np.random.default_rng(0)
    a, b = body(rng), sparse_pocket(rng)
    x = np.vstack([a, b])
    labels = np.zeros(x.shape[0], dtype=int)
    whole = GateIndex(x, labels, PARAMS)
    assert np.mean(whole.labels(pocket_frames(rng, b)) == 0) > 0.9
    d2 = np.sum((x[:, None] - x[None]) ** 2, axis=2)
    links = np.sqrt(d2[200:, :200].min(1))
    assert links.min() < np.sqrt(whole.gate_sq[0])  # the whole cluster's gate reaches the pocket


def test_a_sparse_pocket_is_detached_and_no_longer_passes_its_terrain():
    rng = np.random.default_rng(0)
    a, b = body(rng), sparse_pocket(rng)
    x = np.vstack([a, b])
    labels = np.zeros(x.shape[0], dtype=int)
    out = detach_small_groups(x, labels, np.ones(x.shape[0]), PARAMS)
    # A remainder smaller than gate_neighbours may stay: it cannot pass a frame by itself.
    assert np.sum(out[200:] == 0) < PARAMS.gate_neighbours
    assert np.all(out[:200] == 0)
    kept = out >= 0
    index = GateIndex(x[kept], out[kept], PARAMS)
    assert np.all(index.labels(pocket_frames(rng, b)) == NOISE)
    assert np.mean(index.labels(body(rng, 50)) == 0) >= 0.9


def test_a_clean_cluster_keeps_every_member_and_its_gate_bit_for_bit():
    for seed in range(5):
        rng = np.random.default_rng(seed)
        n = int(rng.integers(40, 300))
        x = body(rng, n)
        labels = np.zeros(n, dtype=int)
        out = detach_small_groups(x, labels, np.ones(n), PARAMS)
        np.testing.assert_array_equal(out, labels)
        before = GateIndex(x, labels, PARAMS).gate_sq[0]
        assert GateIndex(x[out >= 0], out[out >= 0], PARAMS).gate_sq[0] == before


def test_stragglers_of_the_own_terrain_are_kept():
    # Frames of the same terrain a little off the body, each alone (a blurred frame): fewer
    # than gate_neighbours together cannot pass a frame by themselves, so they are no pocket and
    # keep setting the gate's tail as before.
    rng = np.random.default_rng(4)
    x = np.vstack([body(rng), np.eye(DIM)[:4] * 0.6])
    labels = np.zeros(x.shape[0], dtype=int)
    np.testing.assert_array_equal(
        detach_small_groups(x, labels, np.ones(x.shape[0]), PARAMS), labels
    )


def test_a_lobe_as_large_as_a_cluster_stays():
    # A dense group HDBSCAN kept in the cluster that stands for min_cluster_size frames is not a
    # pocket, however far from the body.
    rng = np.random.default_rng(5)
    lobe = rng.normal(0.0, 0.05, (PARAMS.min_cluster_size, DIM))
    lobe[:, 1] += 1.0
    x = np.vstack([body(rng), lobe])
    out = detach_small_groups(x, np.zeros(x.shape[0], dtype=int), np.ones(x.shape[0]), PARAMS)
    np.testing.assert_array_equal(out, 0)


def test_foreign_groups_do_not_pass_as_one_lobe():
    # Three small groups of other terrains, each far from the body and from each other, that
    # together stand for more than min_cluster_size frames: judged at the rest's gate they are
    # three pockets, not one lobe.
    rng = np.random.default_rng(7)
    groups = []
    for axis in (1, 2, 3):
        g = rng.normal(0.0, 0.05, (12, DIM))
        g[:, axis] += 1.0
        groups.append(g)
    # Sparse frames on the way from the body to them and between them, which widen a gate
    # judged over all members until it links everything.
    centres = np.vstack([np.zeros(DIM), np.eye(DIM)[1:4]])
    sparse = np.array(
        [
            (1.0 - f) * centres[a] + f * centres[b]
            for a, b in ((0, 1), (1, 2), (2, 3))
            for f in (1 / 3, 2 / 3)
        ]
    )
    x = np.vstack([body(rng), *groups, sparse])
    labels = np.zeros(x.shape[0], dtype=int)
    out = detach_small_groups(x, labels, np.ones(x.shape[0]), PARAMS)
    np.testing.assert_array_equal(out[:200], 0)
    assert np.all(out[200:236] == NOISE)


def test_detach_pockets_marks_only_the_pocket():
    rng = np.random.default_rng(6)
    x = np.vstack([body(rng), sparse_pocket(rng)])
    d2 = np.sum((x[:, None] - x[None]) ** 2, axis=2)
    np.fill_diagonal(d2, np.inf)
    pocket = density_gate.detach_pockets(d2, np.ones(x.shape[0]), PARAMS)
    assert not pocket[:200].any()
    assert pocket[200:].sum() > 12 - PARAMS.gate_neighbours


def test_a_lone_stray_does_not_open_a_small_contexts_gate():
    # A context of 29 frames and one frame of another terrain that a re-clustering joined to it
    # (studies/fresh_worlds, world 452): of 30 members the 0.99 quantile of the k-th-neighbour
    # distances is the stray's own, which would open the gate to frames of the stray's terrain
    # (their k-th nearest members are body frames as far away as the stray). The k - 1 largest
    # distances never set the gate, so those frames are noise and the body's still pass.
    rng = np.random.default_rng(8)
    stray = np.zeros(DIM)
    stray[0] = 0.8
    x = np.vstack([body(rng, 29), stray])
    labels = np.zeros(x.shape[0], dtype=int)
    kth = density_gate.kth_member_distances(x, PARAMS.gate_neighbours)
    index = GateIndex(x, labels, PARAMS)
    gate = float(np.sqrt(index.gate_sq[0]))
    assert gate / PARAMS.gate_scale <= np.sort(kth)[-2] < kth[-1]  # not set by the stray's
    foreign = stray + rng.normal(0.0, 0.02, (50, DIM))
    assert np.all(index.labels(foreign) == NOISE)
    assert np.mean(index.labels(body(rng, 50)) == 0) >= 0.9
    # From 200 members on, the gate is the plain quantile, as before.
    big = body(rng, 240)
    plain = PARAMS.gate_scale * np.quantile(
        density_gate.kth_member_distances(big, PARAMS.gate_neighbours), PARAMS.gate_quantile
    )
    big_gate = np.sqrt(GateIndex(big, np.zeros(240, dtype=int), PARAMS).gate_sq[0])
    assert big_gate == plain
