"""The PC-VFE closed loop as one Drake diagram (paper Fig. 3).

``MakeSimulation(scenario, meshcat)`` wires the vehicle station (plant + camera, see
``station.py``) to the estimator and the controller::

    station.image -> features -> clustering --context_id--> fitter
    station.state ----------------------------------------> fitter --theta_hat--> nmpc
    station.state ------------------------------------------------------------> nmpc
    nmpc.actuation -> station.actuation (and fitter.actuation)

plus a ``run_logger`` (the drive log written as the run goes: the one record of the run, from
which the summary and the figures are computed) and, with a Meshcat, the ``meshcat_view``. Any
station works (simulated, LCM, replay): consumers connect a sim-only port only where
``station.HasOutputPort(name)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pydrake.geometry import Meshcat
from pydrake.systems.framework import Diagram, DiagramBuilder

from pcvfe_drake.control.course import Course, load_course
from pcvfe_drake.diagrams.debug_layers import AddDebugLayers
from pcvfe_drake.diagrams.station import SIM_ONLY_OUTPUTS, MakeVehicleStation
from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.runs.runlog import RunLog
from pcvfe_drake.runs.scenario import Scenario, build_terrain_map
from pcvfe_drake.systems.clip_features import ClipFeatures
from pcvfe_drake.systems.context_clustering import ContextClustering
from pcvfe_drake.systems.context_fitter import ContextFitter
from pcvfe_drake.systems.meshcat_view import MeshcatView
from pcvfe_drake.systems.nmpc import Nmpc
from pcvfe_drake.systems.run_logger import RunLogger
from pcvfe_drake.vehicle.params import VehicleParams, load_vehicle


@dataclass
class SimulationParts:
    """What a caller needs besides the diagram: the shared course, map, vehicle, run log."""

    diagram: Diagram
    course: Course
    terrain_map: TerrainMap
    params: VehicleParams
    run_log: RunLog


def MakeSimulation(
    scenario: Scenario,
    meshcat: Meshcat | None = None,
    *,
    log_path: str | Path | None = None,
    debug_layers: bool = True,
    station: Diagram | None = None,
) -> SimulationParts:
    """The closed loop of ``scenario`` as a diagram named ``pcvfe_simulation``.

    Args:
        scenario: the scenario.
        meshcat: a Meshcat (created once by the caller) for the ``meshcat_view``; None: no view.
        log_path: CSV drive log the ``run_logger`` appends to as the run goes (None: in memory).
        debug_layers: with a Meshcat, also the debugging layers under ``/pcvfe/`` (plan,
            friction circle, camera, features; ``debug_layers.AddDebugLayers``).
        station: a station diagram with the station ports (``station.py``): the LCM station
            (``MakeVehicleStation(..., hardware=True)``) or a replay station; None: the
            simulated station of ``scenario``. Sim-only ports (``true_mu``, ``true_terrain``)
            are connected only where the station has them; a replay station's
            ``logged_actuation`` (the input recorded with the drive) feeds the fitter and the
            log instead of the NMPC's command, which then drives nothing.

    Systems (names): ``station`` (exports actuation / state / image / true_mu / true_terrain),
    ``features``, ``clustering``, ``fitter``, ``nmpc``, ``run_logger``, and ``meshcat_view``
    when a Meshcat is given (with ``debug_layers``, also ``plan_view``,
    ``friction_circle_view``, ``camera_view``, ``feature_view``).
    """
    params = load_vehicle(scenario.vehicle)
    terrain_map = build_terrain_map(scenario)
    course = load_course(scenario.course)
    rates = scenario.rates

    builder = DiagramBuilder()
    if station is None:
        station = MakeVehicleStation(scenario, terrain_map=terrain_map, course=course)
    station = builder.AddNamedSystem("station", station)
    features = builder.AddNamedSystem(
        "features",
        ClipFeatures(
            scenario.features.backend,
            lambda_c=scenario.features.lambda_c,
            threads=scenario.features.clip_threads,
        ),
    )
    feature_dim = features.GetOutputPort("features").size()
    clustering = builder.AddNamedSystem(
        "clustering",
        ContextClustering(
            feature_dim,
            scenario.clustering_params(),
            frame_period_s=rates.camera_period_s,
            recluster_period_s=rates.recluster_period_s,
            frame_offset_s=rates.clustering_frame_offset_s,
        ),
    )
    fitter = builder.AddNamedSystem(
        "fitter",
        ContextFitter(
            params,
            period_s=rates.fitter_period_s,
            sample_period_s=rates.fitter_sample_period_s,
            config=scenario.fit_config(),
        ),
    )
    nmpc = builder.AddNamedSystem("nmpc", Nmpc(course, params, scenario.nmpc_config()))

    state = station.GetOutputPort("state")
    builder.Connect(station.GetOutputPort("image"), features.GetInputPort("image"))
    builder.Connect(features.GetOutputPort("features"), clustering.GetInputPort("features"))
    builder.Connect(state, fitter.GetInputPort("state"))
    # What the car did: the NMPC's command, or on a replay the input recorded with the drive.
    applied = (
        station.GetOutputPort("logged_actuation")
        if station.HasOutputPort("logged_actuation")
        else nmpc.GetOutputPort("actuation")
    )
    builder.Connect(applied, fitter.GetInputPort("actuation"))
    builder.Connect(clustering.GetOutputPort("context_id"), fitter.GetInputPort("context_id"))
    builder.Connect(state, nmpc.GetInputPort("state"))
    builder.Connect(fitter.GetOutputPort("theta_hat"), nmpc.GetInputPort("theta_hat"))
    builder.Connect(nmpc.GetOutputPort("actuation"), station.GetInputPort("actuation"))

    run_log = RunLog(
        log_path, terrain_map.names, feature_dim, frame_period_s=rates.frame_log_period_s
    )
    logger = builder.AddNamedSystem("run_logger", RunLogger(run_log, rates.log_period_s))
    sources = {
        "state": state,
        "actuation": applied,
        "features": features.GetOutputPort("features"),
        "context_id": clustering.GetOutputPort("context_id"),
        "theta_hat": fitter.GetOutputPort("theta_hat"),
        "image": station.GetOutputPort("image"),
    }
    for name in SIM_ONLY_OUTPUTS:  # truth only where the station has it
        if station.HasOutputPort(name):
            sources[name] = station.GetOutputPort(name)
    for name, port in sources.items():
        builder.Connect(port, logger.GetInputPort(name))

    if meshcat is not None:
        view = builder.AddNamedSystem(
            "meshcat_view",
            MeshcatView(
                meshcat,
                terrain_map,
                course_xy(course),
                vehicle_length_m=params.length,
                vehicle_width_m=params.width,
                period_s=rates.view_period_s,
            ),
        )
        for name in ("state", "context_id", "theta_hat", "true_mu"):
            if name in sources:
                builder.Connect(sources[name], view.GetInputPort(name))
        if debug_layers:
            AddDebugLayers(
                builder,
                meshcat,
                station=station,
                nmpc=nmpc,
                theta_hat=fitter.GetOutputPort("theta_hat"),
                features=features,
                clustering=clustering,
                terrain_map=terrain_map,
                view_period_s=rates.view_period_s,
            )

    diagram = builder.Build()
    diagram.set_name("pcvfe_simulation")
    return SimulationParts(diagram, course, terrain_map, params, run_log)


def course_xy(course: Course):
    """(N, 2) points of the course's reference path [m]."""
    import numpy as np

    return np.column_stack([course.x, course.y])
