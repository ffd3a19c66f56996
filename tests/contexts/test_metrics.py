"""Context metrics on hand-made label sequences with known answers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pcvfe_drake.contexts.metrics import (
    adjusted_rand,
    context_metrics,
    first_id_times,
    included_mask,
    n_contexts,
    noise_fraction,
    reidentification_latencies,
    terrain_visits,
)

# 10 Hz samples: grass, a transition, brick, transition, grass again, brick again.
LABELS = (
    ["grass"] * 5 + ["transition"] + ["brick"] * 4 + ["transition"] + ["grass"] * 4 + ["brick"] * 3
)
T = 0.1 * np.arange(len(LABELS))


def test_ari_ignores_transitions_and_id_names():
    pred = [7] * 5 + [-1] + [3] * 4 + [7] + [7] * 4 + [3] * 3
    assert adjusted_rand(LABELS, pred) == pytest.approx(1.0)
    # Transition samples are excluded: whatever is reported there does not matter.
    pred2 = list(pred)
    pred2[5] = 3
    assert adjusted_rand(LABELS, pred2) == pytest.approx(1.0)
    # Noise counts as a label of its own: all noise scores 0, one wrong sample scores < 1.
    assert adjusted_rand(LABELS, [-1] * len(LABELS)) == pytest.approx(0.0)
    pred3 = list(pred)
    pred3[0] = 3
    assert adjusted_rand(LABELS, pred3) < 0.9
    # A mask drops samples as well.
    mask = np.ones(len(LABELS), dtype=bool)
    mask[0] = False
    assert adjusted_rand(LABELS, pred3, mask=mask) == pytest.approx(1.0)


def test_counts_and_noise_fraction():
    pred = np.array([0, 0, -1, 2, 2, 5, -1])
    assert n_contexts(pred) == 3
    assert noise_fraction(pred) == pytest.approx(2 / 7)
    assert noise_fraction(pred, include=pred >= 0) == 0.0
    assert math.isnan(noise_fraction(np.array([], dtype=int)))
    keep = included_mask([0, -1, 1, -2, "transition", None, float("nan"), 3])
    assert keep.tolist() == [True, False, True, False, False, False, False, True]


def test_visits_skip_excluded_samples():
    labels = np.array(["a", "a", "outlier", "a", "transition", "b", "b", "a"], dtype=object)
    visits = terrain_visits(labels, included_mask(labels))
    assert [(v.label, v.start, v.stop) for v in visits] == [("a", 0, 4), ("b", 5, 7), ("a", 7, 8)]


def test_reidentification_latency_known_answer():
    # grass gets id 0 at once; brick is noise for two samples, then 1. On the revisit of grass
    # (starting t=1.1 s) the id 0 comes back after two noise samples: latency 0.2 s. The brick
    # revisit (t=1.5 s) reports its id 1 at once.
    pred = [0] * 5 + [-1] + [-1, -1, 1, 1] + [-1] + [-1, -1, 0, 0] + [1, 1, 1]
    reid = reidentification_latencies(T, LABELS, pred)
    assert [(lab, round(t0, 6)) for lab, t0, _ in reid] == [("grass", 1.1), ("brick", 1.5)]
    assert [lat for *_, lat in reid] == pytest.approx([0.2, 0.0])
    first = first_id_times(T, LABELS, pred)
    assert first == pytest.approx({"grass": 0.0, "brick": 0.2})


def test_missed_revisit_and_majority_id():
    # On the grass revisit the method reports brick's id: never re-identified (inf). The id of
    # grass is the majority of what it had before (0, not the single 9).
    pred = [0, 0, 9, 0, 0] + [-1] + [1] * 4 + [-1] + [1] * 4 + [1] * 3
    m = context_metrics(T, LABELS, pred)
    assert m.n_revisits == 2
    assert m.n_reid_missed == 1
    assert math.isinf(m.reid_latency_max_s)
    assert m.reid_latencies_s[1] == 0.0
    assert m.n_contexts == 3
    assert m.n_included == len(LABELS) - 2
    # A terrain that never gets an id.
    first = first_id_times(T, LABELS, [-1] * len(LABELS))
    assert all(math.isinf(v) for v in first.values())
    # The summary serialises.
    assert json.loads(json.dumps(m.to_dict()))["n_contexts"] == 3


def test_integer_labels_and_float_ids():
    labels = np.array([0, 0, 0, -1, 1, 1, 1, -2, 0, 0])
    pred = np.array([4.0, 4, 4, -1, -1, 6, 6, -1, -1, 4])
    m = context_metrics(np.arange(10) * 0.5, labels, pred)
    assert m.ari < 1.0
    assert m.first_id_time_s == pytest.approx({"0": 0.0, "1": 0.5})
    assert m.reid_latencies_s == pytest.approx([0.5])
    assert m.noise_fraction == pytest.approx(2 / 8)


def test_bad_input_is_reported():
    with pytest.raises(ValueError, match="same length"):
        context_metrics([0.0, 0.1], ["a"], [0])
    with pytest.raises(ValueError, match="nondecreasing"):
        context_metrics([0.0, 0.2, 0.1], ["a"] * 3, [0] * 3)
    with pytest.raises(ValueError, match="integers"):
        context_metrics([0.0, 0.1], ["a"] * 2, [0.5, 1.0])
    with pytest.raises(ValueError, match="mask"):
        adjusted_rand(["a", "b"], [0, 1], mask=[True])
