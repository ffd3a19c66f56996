"""The Meshcat debugging layers added to a closed-loop diagram (``/pcvfe/plan``,
``/pcvfe/friction_circle``, ``/pcvfe/camera``, ``/pcvfe/features``; see docs/simulation.md).

:func:`AddDebugLayers` connects them to the systems of a :func:`MakeSimulation` builder. They
work on every station: the friction circle draws the true mu only where the station exports
``true_mu`` (``station.HasOutputPort("true_mu")``), and nothing else needs truth.
"""

from __future__ import annotations

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.systems.framework import DiagramBuilder

from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.perception.texture_library import default_textures
from pcvfe_drake.systems.camera_view import CameraView
from pcvfe_drake.systems.feature_view import FeatureView
from pcvfe_drake.systems.friction_circle_view import FrictionCircleView
from pcvfe_drake.systems.plan_view import PlanView
from pcvfe_drake.views.labels import FrameCaptioner

LAYERS = ("plan", "friction_circle", "camera", "features")
# The plan's speed colours span 0 .. 1.5 x the fastest reference speed (at mu = 1): driving at
# the reference is yellow, faster red, braking green to blue.
MU_COLOUR_SCALE = 1.0
SPEED_COLOUR_MARGIN = 1.5


def _captioner(features, terrain_map: TerrainMap) -> FrameCaptioner | None:
    textures = default_textures()
    names = [t.texture for t in terrain_map.terrains if t.texture in textures.names]
    if not names:
        return None
    return FrameCaptioner.for_textures(features.extractor, textures, names)


def AddDebugLayers(
    builder: DiagramBuilder,
    meshcat: Meshcat,
    *,
    station,
    nmpc,
    theta_hat,
    features=None,
    clustering=None,
    terrain_map: TerrainMap,
    view_period_s: float = 0.1,
    camera_period_s: float = 0.5,
) -> dict[str, object]:
    """Adds and connects the layer systems; returns them by layer name.

    Systems (names): ``plan_view``, ``friction_circle_view`` (from the ``station``'s ``state``,
    the ``nmpc``'s ``plan`` and ``actuation``, and the ``theta_hat`` output port the NMPC is
    given; the station's ``true_mu`` where it exists), ``camera_view`` where the station has an
    ``image`` (with the frame's caption where there is a ``features`` system, and its context
    where there is a ``clustering``), and ``feature_view`` where there are both.
    """
    state = station.GetOutputPort("state")
    horizon = nmpc.controller.N
    v_max = SPEED_COLOUR_MARGIN * float(np.max(nmpc.controller.profile(MU_COLOUR_SCALE).v))
    plan = builder.AddNamedSystem(
        "plan_view",
        PlanView(meshcat, horizon=horizon, v_max_mps=max(v_max, 1.0), period_s=view_period_s),
    )
    builder.Connect(nmpc.GetOutputPort("plan"), plan.GetInputPort("plan"))
    builder.Connect(state, plan.GetInputPort("state"))

    has_truth = station.HasOutputPort("true_mu")
    circle = builder.AddNamedSystem(
        "friction_circle_view",
        FrictionCircleView(meshcat, has_truth=has_truth, horizon=horizon, period_s=view_period_s),
    )
    builder.Connect(state, circle.GetInputPort("state"))
    builder.Connect(nmpc.GetOutputPort("actuation"), circle.GetInputPort("actuation"))
    builder.Connect(theta_hat, circle.GetInputPort("theta_hat"))
    builder.Connect(nmpc.GetOutputPort("plan"), circle.GetInputPort("plan"))
    if has_truth:
        builder.Connect(station.GetOutputPort("true_mu"), circle.GetInputPort("true_mu"))
    layers = {"plan": plan, "friction_circle": circle}
    if not station.HasOutputPort("image"):
        return layers

    feature_dim = features.GetOutputPort("features").size() if features is not None else 1
    camera = builder.AddNamedSystem(
        "camera_view",
        CameraView(
            meshcat,
            feature_dim,
            caption=_captioner(features, terrain_map) if features is not None else None,
            frame_period_s=camera_period_s,
        ),
    )
    builder.Connect(station.GetOutputPort("image"), camera.GetInputPort("image"))
    builder.Connect(state, camera.GetInputPort("state"))
    layers["camera"] = camera
    if features is not None:
        builder.Connect(features.GetOutputPort("features"), camera.GetInputPort("features"))
    if clustering is None:
        return layers
    builder.Connect(clustering.GetOutputPort("context_id"), camera.GetInputPort("context_id"))
    if features is None:
        return layers

    x0, x1, y0, y1 = terrain_map.bounds_m
    size = 0.5 * max(y1 - y0, 1.0)
    feature_view = builder.AddNamedSystem(
        "feature_view",
        FeatureView(
            meshcat,
            feature_dim,
            origin_m=(x1 + 0.7 * size, 0.5 * (y0 + y1), 0.6 * size),
            size_m=size,
            period_s=view_period_s,
        ),
    )
    builder.Connect(features.GetOutputPort("features"), feature_view.GetInputPort("features"))
    for name in ("context_id", "cluster_table", "stored_features"):
        builder.Connect(clustering.GetOutputPort(name), feature_view.GetInputPort(name))
    layers["features"] = feature_view
    return layers
