"""MeshcatView: the scene objects appear, the trail is published in chunks, bad input fails."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from pcvfe_drake.perception.terrain import Terrain, TerrainMap
from pcvfe_drake.systems.meshcat_view import MeshcatView


@pytest.fixture(scope="module")
def meshcat():
    params = MeshcatParams()
    params.host = "localhost"
    return Meshcat(params)


def small_map() -> TerrainMap:
    labels = np.zeros((20, 40), dtype=np.uint8)
    labels[:, 20:] = 1
    terrains = [Terrain("sand", 0.45, "sand"), Terrain("brick", 0.8, "brick")]
    return TerrainMap(labels, terrains, x_min_m=-20.0, y_min_m=-10.0, resolution_m=1.0)


def test_scene_trail_and_context_markers(meshcat):
    ground = np.full((20, 40, 3), 128, np.uint8)
    circle = np.linspace(0, 2 * np.pi, 50)
    view = MeshcatView(
        meshcat,
        small_map(),
        np.column_stack([8 * np.cos(circle), 5 * np.sin(circle)]),
        period_s=0.1,
        trail_chunk_s=0.5,
        ground_image=ground,
    )
    builder = DiagramBuilder()
    builder.AddNamedSystem("view", view)
    values = {
        "state": [1.0, 2.0, 0.0, 5.0, 0.3, 0.0, 0.0],
        "context_id": [2.0],
        "theta_hat": [0.6, 20.0, 20.0],
        "true_mu": [0.45],
    }
    for name, value in values.items():
        source = builder.AddSystem(ConstantVectorSource(np.array(value)))
        builder.Connect(source.get_output_port(), view.GetInputPort(name))
    simulator = Simulator(builder.Build())
    meshcat.StartRecording()
    simulator.AdvanceTo(1.05)  # 11 publishes: two full trail chunks of 5 points
    meshcat.StopRecording()
    for path in ("ground", "reference", "car/body", "car/mu_hat", "car/mu_true", "car/context/2"):
        assert meshcat.HasPath(f"/pcvfe/{path}"), path
    assert meshcat.HasPath("/pcvfe/driven/00001")
    assert not meshcat.HasPath("/pcvfe/driven/00002")
    assert not meshcat.HasPath("/pcvfe/car/context/0")
    meshcat.DeleteRecording()


def test_bad_arguments_are_rejected(meshcat):
    with pytest.raises(ValueError, match="period_s"):
        MeshcatView(meshcat, small_map(), np.zeros((3, 2)), period_s=0.0)
    with pytest.raises(ValueError, match="reference_xy"):
        MeshcatView(meshcat, small_map(), np.zeros((3, 3)))
