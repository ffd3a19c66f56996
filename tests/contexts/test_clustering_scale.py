"""Feature vectors of absurd magnitude are corrupt frames, not a memory exhaustion in HDBSCAN."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.contexts.clustering import MAX_ABS_FEATURE, NOISE, ContextClusterer


def test_absurd_features_are_refused_and_reported():
    clusterer = ContextClusterer()
    rng = np.random.default_rng(0)
    with pytest.warns(RuntimeWarning, match="1.2e\\+154.*feature extractor"):
        for i in range(300):
            z = rng.normal(size=8) * 0.1 + (i // 150)  # two terrains
            if i % 7 == 0:
                z[3] = 1.2e154  # squared distances overflow to inf from here
            context_id = clusterer.assign(z, 0.1 * i)
            if i % 7 == 0:
                assert context_id == NOISE
            if i % 50 == 49:
                clusterer.recluster(0.1 * i)  # exhausted the memory before the bound existed
    assert clusterer.n_rejected == 43
    assert clusterer.n_stored == 300 - 43
    assert len(clusterer.table().active_ids) == 2
    huge = np.full((2, 8), 2.0 * MAX_ABS_FEATURE)
    assert (clusterer.predict(huge) == NOISE).all()
