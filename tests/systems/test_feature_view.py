"""FeatureView: nothing before the first re-clustering; then the store as a cloud in PCA
coordinates with ids at the centroids, the current frame projected with the same fit; a new
re-clustering replaces the cloud."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from pcvfe_drake.contexts.clustering import ClusterTable, StoredFeatures
from pcvfe_drake.systems.feature_view import FeatureView
from pcvfe_drake.views.feature_projection import PcaProjection

D = 6


@pytest.fixture
def meshcat(local_meshcat_server):
    return local_meshcat_server


def planted_store(n_reclusterings: int) -> StoredFeatures:
    rng = np.random.default_rng(0)
    centres = np.eye(D)[:3] * 2.0
    z = np.vstack([c + 0.05 * rng.standard_normal((20, D)) for c in centres])
    z = np.vstack([z, rng.uniform(-1, 1, (5, D))])
    labels = np.repeat([0, 1, 2, -1], [20, 20, 20, 5])
    return StoredFeatures(z, labels, np.arange(len(z)) * 0.1, n_reclusterings)


def test_cloud_ids_and_current_frame(meshcat, probe):
    view = FeatureView(meshcat, D, origin_m=(100.0, 0.0, 15.0), size_m=30.0)
    simulator = Simulator(view)
    context = simulator.get_mutable_context()
    store = planted_store(0)
    z_now = store.z[3]
    view.GetInputPort("features").FixValue(context, z_now)
    view.GetInputPort("context_id").FixValue(context, np.array([0.0]))
    view.GetInputPort("cluster_table").FixValue(context, ClusterTable(n_reclusterings=0))
    view.GetInputPort("stored_features").FixValue(context, store)
    simulator.AdvanceTo(0.15)
    assert view.projection is None and not meshcat.HasPath("/pcvfe/features/clouds/00000")

    view.GetInputPort("cluster_table").FixValue(context, ClusterTable(n_reclusterings=1))
    view.GetInputPort("stored_features").FixValue(context, planted_store(1))
    simulator.AdvanceTo(0.25)
    fit = view.projection
    expected = PcaProjection.fit(store.z, size_m=30.0, origin_m=(100.0, 0.0, 15.0))
    np.testing.assert_allclose(fit.project(store.z), expected.project(store.z))
    points = fit.project(store.z)
    assert np.max(np.abs(points - [100.0, 0.0, 15.0])) == pytest.approx(15.0)
    cloud = "/pcvfe/features/clouds/00000"
    assert meshcat.HasPath(f"{cloud}/points")
    for k in (0, 1, 2):
        np.testing.assert_allclose(
            probe.translation(meshcat, f"{cloud}/ids/{k}"),
            points[store.labels == k].mean(axis=0) + [0.0, -1.0, 1.5],
        )
    assert not meshcat.HasPath(f"{cloud}/ids/-1")  # noise has no id
    np.testing.assert_allclose(probe.translation(meshcat, "/pcvfe/features/current"), points[3])
    assert view._current.shown == 0

    view.GetInputPort("cluster_table").FixValue(context, ClusterTable(n_reclusterings=2))
    view.GetInputPort("stored_features").FixValue(context, planted_store(2))
    simulator.AdvanceTo(0.35)
    assert probe.visible(meshcat, "/pcvfe/features/clouds/00001") is True
    assert probe.visible(meshcat, cloud) is False


def test_bad_arguments(meshcat):
    with pytest.raises(ValueError, match="size_m"):
        FeatureView(meshcat, D, size_m=0.0)
