"""The vehicle station: the car and its downward camera behind a fixed set of exported ports.

``MakeVehicleStation(scenario, meshcat, hardware=False)`` returns a Diagram whose exported ports
are the contract between the vehicle and everything that estimates or controls it, so that
``MakeSimulation`` and any other consumer connect only to these names, whichever station is
built. The simulated station (``hardware=False``) holds the ``VehiclePlant`` (single-track or
multi-body truth over the scenario's terrain map) and the ``TextureCamera``; the hardware
station (``hardware=True``: ``MakeLcmStation`` in ``hardware_station.py``, the real car or
``pcvfe vehicle-bridge`` over LCM) exports the same ports:

====================  ======  ===============================================================
port                  dir     meaning
====================  ======  ===============================================================
``actuation``         input   (2) [steer_rate rad/s, accel m/s^2]
``state``             output  (7) measured ST state [sx, sy, delta, v, psi, psi_dot, beta] (SI
                              units): the scenario's ``sensing`` model applied to the truth
``image``             output  abstract Drake image of the downward camera (RGBA, 8 bit)
``station_status``    output  abstract ``pcvfe_drake.hardware.watchdog.StationStatus``: whether
                              ``state`` and ``image`` are live, and if not why (always ``ok``
                              in simulation; the LCM station's watchdog fills it)
``true_mu``           output  (1) **sim only**: true friction coefficient under the car
``true_terrain``      output  (1) **sim only**: index of the true terrain (-1: none)
``true_state``        output  (7) **sim only**: the true ST state
====================  ======  ===============================================================

The hardware station (``hardware_station.py``, ``hardware=True``) exports the same ports
without the sim-only ones (``SIM_ONLY_OUTPUTS``); consumers connect a sim-only port only where
``station.HasOutputPort(name)``.
"""

from __future__ import annotations

import dataclasses

from pydrake.common.value import AbstractValue
from pydrake.geometry import Meshcat
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource

from pcvfe_drake.control.course import Course, initial_state
from pcvfe_drake.diagrams.world_io import scenario_world
from pcvfe_drake.hardware.watchdog import StationStatus
from pcvfe_drake.perception.camera import CameraConfig
from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.runs.scenario import Scenario
from pcvfe_drake.systems.state_sensor import StateSensor
from pcvfe_drake.systems.texture_camera import TextureCamera
from pcvfe_drake.systems.vehicle_plant import VehiclePlant
from pcvfe_drake.vehicle.params import load_vehicle

STATION_INPUTS = ("actuation",)
"""Input ports of every station variant."""
STATION_OUTPUTS = ("state", "image", "station_status")
"""Output ports of every station variant."""
SIM_ONLY_OUTPUTS = ("true_mu", "true_terrain", "true_state")
"""Outputs of the simulated station only (ground truth a real car does not have)."""


def camera_config(scenario: Scenario) -> CameraConfig:
    """The scenario's camera (a copy, validated)."""
    return dataclasses.replace(scenario.camera)


def MakeVehicleStation(
    scenario: Scenario,
    meshcat: Meshcat | None = None,
    *,
    hardware: bool = False,
    terrain_map: TerrainMap | None = None,
    course: Course | None = None,
    lcm_buses=None,
) -> Diagram:
    """The station diagram of ``scenario`` (named ``vehicle_station``; ports in the module doc).

    Args:
        scenario: the scenario (vehicle, truth model, world, camera, rates, seed).
        meshcat: accepted so every station factory has the same signature; the simulated
            station draws nothing itself (``MakeSimulation`` adds the ``MeshcatView``).
        hardware: True builds the LCM station instead (``hardware_station.py``): the same
            ports without the sim-only ones, plus ``station_status``.
        terrain_map, course: already built ones to share (default: built from the scenario).
        lcm_buses: (hardware only) ``pydrake.systems.lcm.LcmBuses`` to use instead of those of
            the scenario's ``hardware.lcm_buses``.

    Subsystems: ``plant`` (VehiclePlant, its default state on the course at the scenario's
    start_s_m and initial speed, the multi-body truth's tire mapping ``friction_mapping``),
    ``camera`` (TextureCamera, on the true pose), ``status`` (a constant ``ok``
    ``station_status``) and, with ``sensing.model`` other than ``none``, ``sensor``
    (StateSensor) between the plant's state and the exported ``state``.
    """
    if hardware:
        from pcvfe_drake.diagrams.hardware_station import MakeLcmStation

        return MakeLcmStation(scenario, meshcat, lcm_buses=lcm_buses)
    params = load_vehicle(scenario.vehicle)
    if terrain_map is None or course is None:
        world = scenario_world(scenario, params)
        terrain_map = terrain_map if terrain_map is not None else world.terrain_map
        course = course if course is not None else world.course
    x0 = initial_state(course, params, scenario.initial_speed_mps, scenario.start_s_m)

    builder = DiagramBuilder()
    plant = builder.AddNamedSystem(
        "plant",
        VehiclePlant(
            params,
            terrain_map=terrain_map,
            truth=scenario.truth_model,
            x0=x0,
            friction_scaling=scenario.friction_mapping,
            # the MB state advances on the grid every periodic reader samples on
            mb_period_s=scenario.rates.fitter_sample_period_s,
        ),
    )
    camera = builder.AddNamedSystem(
        "camera",
        TextureCamera(
            terrain_map,
            camera_config(scenario),
            period_s=scenario.rates.camera_period_s,
            seed=scenario.seed,
        ),
    )
    status = builder.AddNamedSystem(
        "status", ConstantValueSource(AbstractValue.Make(StationStatus(source="sim")))
    )
    builder.Connect(plant.GetOutputPort("state"), camera.GetInputPort("state"))
    builder.ExportInput(plant.GetInputPort("actuation"), "actuation")
    true_state = plant.GetOutputPort("state")
    state = true_state
    if scenario.sensing.enabled:
        sensor = builder.AddNamedSystem("sensor", StateSensor(scenario.sensing, scenario.seed))
        builder.Connect(true_state, sensor.GetInputPort("true_state"))
        state = sensor.GetOutputPort("state")
    builder.ExportOutput(state, "state")
    builder.ExportOutput(camera.GetOutputPort("image"), "image")
    builder.ExportOutput(status.get_output_port(), "station_status")
    builder.ExportOutput(plant.GetOutputPort("true_mu"), "true_mu")
    builder.ExportOutput(plant.GetOutputPort("true_terrain"), "true_terrain")
    builder.ExportOutput(true_state, "true_state")
    diagram = builder.Build()
    diagram.set_name("vehicle_station")
    return diagram
