"""The PC-VFE closed loop as one Drake diagram (paper Fig. 3).

``MakeSimulation(scenario, meshcat)`` wires the vehicle station (plant + sensing + camera, see
``station.py``) to the friction source and the controller; with ``estimator: pcvfe``::

    station.image -> features -> clustering --context_id, frame_labels--> fitter
    station.state ------------------------------------------------------> fitter --theta_hat--> nmpc
    station.state ------------------------------------------------------------------------> nmpc
    nmpc.actuation -> station.actuation (and fitter.actuation)

Other friction sources replace clustering + fitter by one ``friction_source`` system with the
same ``theta_hat`` output (``_add_friction_source``); ``kmpc`` also switches the NMPC to the
kinematic model.

plus a ``run_logger`` (the drive log written as the run goes: the one record of the run, from
which the summary and the figures are computed) and, with a Meshcat, the ``meshcat_view``. Any
station works (simulated, LCM, replay): consumers connect a sim-only port only where
``station.HasOutputPort(name)``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from pydrake.geometry import Meshcat
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from pcvfe_drake.control.course import Course
from pcvfe_drake.control.nmpc import NmpcConfig
from pcvfe_drake.diagrams.debug_layers import AddDebugLayers
from pcvfe_drake.diagrams.station import SIM_ONLY_OUTPUTS, MakeVehicleStation
from pcvfe_drake.diagrams.world_io import scenario_world
from pcvfe_drake.estimation.lookup import build_lookup_table
from pcvfe_drake.perception.features import make_extractor
from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.runs.friction_sources import PCVFE_SOURCES, fixed_mu
from pcvfe_drake.runs.runlog import RunLog
from pcvfe_drake.runs.scenario import Scenario
from pcvfe_drake.systems.clip_features import ClipFeatures
from pcvfe_drake.systems.context_clustering import ContextClustering
from pcvfe_drake.systems.context_fitter import ContextFitter, HeldSamples, samples_per_period
from pcvfe_drake.systems.lookup_friction import LookupFriction
from pcvfe_drake.systems.meshcat_view import MeshcatView
from pcvfe_drake.systems.nmpc import Nmpc
from pcvfe_drake.systems.oracle_friction import OracleFriction
from pcvfe_drake.systems.run_logger import RunLogger
from pcvfe_drake.systems.ukf_friction import UkfFriction
from pcvfe_drake.vehicle.params import VehicleParams, load_vehicle
from pcvfe_drake.vehicle.sensing import StateSensorModel


@dataclass
class SimulationParts:
    """What a caller needs besides the diagram: the shared course, map, vehicle, run log."""

    diagram: Diagram
    course: Course
    terrain_map: TerrainMap
    params: VehicleParams
    run_log: RunLog


def nmpc_config(scenario: Scenario) -> NmpcConfig:
    """The scenario's NMPC settings; ``estimator: kmpc`` switches to the kinematic model."""
    config = scenario.nmpc_config()
    if scenario.estimator == "kmpc":
        config = dataclasses.replace(config, model="ks")
    return config


def _decision_period(rates) -> float | None:
    """The fitter decides ``theta_hat`` at the NMPC's period when it is a whole multiple of
    the sampling period (the NMPC reads it at that period's multiples), else at every sample."""
    if samples_per_period(rates.nmpc_period_s, rates.fitter_sample_period_s):
        return rates.nmpc_period_s
    return None


def _add_friction_source(
    builder, scenario: Scenario, params, station, features, actuation, refit_worker=False
):
    """Add the scenario's friction source (``scenario.estimator``), reading the ``features``
    output port; returns its ``theta_hat`` output and the port logged as the run's ``context``
    column.

    ``pcvfe`` and ``pcvfe_paper``: ``clustering`` (ContextClustering) and ``fitter``
    (ContextFitter), the context id from the clustering. ``oracle``: ``friction_source``
    (OracleFriction on ``true_mu``).
    ``lookup``: ``friction_source`` (LookupFriction on the features; its class is the context).
    ``ukf``: ``friction_source`` (UkfFriction on the measured state and the actuation).
    ``fixed`` and ``kmpc``: ``friction_source``, a ConstantVectorSource. Sources without
    contexts log the context -1 (``no_context``).
    """
    rates = scenario.rates
    kind = scenario.estimator
    feature_dim = features.size()
    if kind in PCVFE_SOURCES:
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
                latency_s=rates.fitter_latency_s,
                refit_worker=refit_worker,
                config=scenario.fit_config(),
                planner_mu_share=scenario.nmpc.speed_margin**2,  # the NMPC's share of mu
                decision_period_s=_decision_period(rates),
            ),
        )
        builder.Connect(features, clustering.GetInputPort("features"))
        builder.Connect(station.GetOutputPort("state"), clustering.GetInputPort("state"))
        takers = [fitter]
        if fitter.decision_period_s > rates.fitter_sample_period_s:
            held = builder.AddNamedSystem(
                "fitter_samples",
                HeldSamples(
                    sample_period_s=rates.fitter_sample_period_s,
                    capacity=fitter.held_capacity,
                    relabel=fitter.config.relabel,
                ),
            )
            builder.Connect(held.get_output_port(), fitter.GetInputPort("held_samples"))
            takers.append(held)
        for taker in takers:
            builder.Connect(station.GetOutputPort("state"), taker.GetInputPort("state"))
            builder.Connect(actuation, taker.GetInputPort("actuation"))
            builder.Connect(
                clustering.GetOutputPort("context_id"), taker.GetInputPort("context_id")
            )
            builder.Connect(
                clustering.GetOutputPort("frame_labels"), taker.GetInputPort("frame_labels")
            )
        return fitter.GetOutputPort("theta_hat"), clustering.GetOutputPort("context_id")
    if kind == "lookup":
        table = build_lookup_table(
            make_extractor(
                "clip" if scenario.uses_clip else "descriptor",
                scenario.features.backend if scenario.uses_clip else None,
                lambda_c=scenario.features.lambda_c,
                threads=scenario.features.clip_threads,
            ),
            scenario.lookup.classes,
            camera_config=scenario.camera,
            frames_per_class=scenario.lookup.frames_per_class,
            seed=scenario.seed,
            default_mu=scenario.lookup.default_mu,
            reject_factor=scenario.lookup.reject_factor,
        )
        source = builder.AddNamedSystem(
            "friction_source",
            LookupFriction(
                table,
                params,
                period_s=rates.camera_period_s,
                offset_s=rates.clustering_frame_offset_s,
            ),
        )
        builder.Connect(features, source.GetInputPort("features"))
        return source.GetOutputPort("theta_hat"), source.GetOutputPort("terrain_class")
    if kind == "oracle":
        if not station.HasOutputPort("true_mu"):
            raise ValueError(
                "estimator 'oracle' needs the simulated station's true_mu; this station has "
                "none (hardware): choose pcvfe, fixed, lookup, ukf or kmpc"
            )
        source = builder.AddNamedSystem(
            "friction_source", OracleFriction(params, period_s=rates.fitter_sample_period_s)
        )
        builder.Connect(station.GetOutputPort("true_mu"), source.GetInputPort("true_mu"))
    elif kind == "ukf":
        sigma = StateSensorModel(scenario.sensing, scenario.seed).sigma
        source = builder.AddNamedSystem(
            "friction_source",
            UkfFriction(params, sigma, scenario.ukf_config()),
        )
        builder.Connect(station.GetOutputPort("state"), source.GetInputPort("state"))
        builder.Connect(actuation, source.GetInputPort("actuation"))
    else:  # fixed, kmpc
        settings = scenario.fixed
        if kind == "kmpc":
            settings = dataclasses.replace(settings, use="nominal")
        mu = fixed_mu(settings, params.mu)
        source = builder.AddNamedSystem(
            "friction_source", ConstantVectorSource([mu, params.C_Sf, params.C_Sr])
        )
    no_context = builder.AddNamedSystem("no_context", ConstantVectorSource([-1.0]))
    return source.get_output_port(0), no_context.get_output_port()


def MakeSimulation(
    scenario: Scenario,
    meshcat: Meshcat | None = None,
    *,
    log_path: str | Path | None = None,
    debug_layers: bool = True,
    station: Diagram | None = None,
    refit_worker: bool = False,
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
        refit_worker: the fitter's refits run in a worker thread (``ContextFitter``'s
            ``refit_worker``): for a loop paced to the wall clock (the LCM station).

    Systems (names): ``station`` (exports actuation / state / image / true_mu / true_terrain),
    ``features``, ``clustering``, ``fitter``, ``nmpc``, ``run_logger``, and ``meshcat_view``
    when a Meshcat is given (with ``debug_layers``, also ``plan_view``,
    ``friction_circle_view``, ``camera_view``, ``feature_view``).
    """
    params = load_vehicle(scenario.vehicle)
    world = scenario_world(scenario, params)
    terrain_map, course = world.terrain_map, world.course
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
    nmpc = builder.AddNamedSystem("nmpc", Nmpc(course, params, nmpc_config(scenario)))
    state = station.GetOutputPort("state")
    builder.Connect(station.GetOutputPort("image"), features.GetInputPort("image"))
    # What the car did: the NMPC's command, or on a replay the input recorded with the drive.
    applied = (
        station.GetOutputPort("logged_actuation")
        if station.HasOutputPort("logged_actuation")
        else nmpc.GetOutputPort("actuation")
    )
    # What the perception saw: features of the camera's images, or on a replay of a run the
    # features that run computed (its drive log holds those of every frame, its frames/ not).
    seen = features.GetOutputPort("features")
    if station.HasOutputPort("logged_features"):
        seen = station.GetOutputPort("logged_features")
        if seen.size() != feature_dim:
            raise ValueError(
                f"replay: the log holds {seen.size()} features per frame, the scenario's "
                f"feature backend {feature_dim}"
            )
    theta_hat, context_id = _add_friction_source(
        builder, scenario, params, station, seen, applied, refit_worker
    )
    builder.Connect(state, nmpc.GetInputPort("state"))
    builder.Connect(theta_hat, nmpc.GetInputPort("theta_hat"))
    builder.Connect(nmpc.GetOutputPort("actuation"), station.GetInputPort("actuation"))

    run_log = RunLog(
        log_path, terrain_map.names, feature_dim, frame_period_s=rates.frame_log_period_s
    )
    logger = builder.AddNamedSystem(
        "run_logger",
        RunLogger(run_log, rates.log_period_s, sample_period_s=rates.fitter_sample_period_s),
    )
    sources = {
        "state": state,
        "actuation": applied,
        "features": seen,
        "context_id": context_id,
        "theta_hat": theta_hat,
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
                theta_hat=theta_hat,
                features=features if builder.HasSubsystemNamed("clustering") else None,
                clustering=(
                    builder.GetSubsystemByName("clustering")
                    if builder.HasSubsystemNamed("clustering")
                    else None
                ),
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
