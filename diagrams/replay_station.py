"""The replay station: a recorded drive (a run folder, or a drive log imported from a ROS 2 bag)
played out of the station's ports, so the estimator can be rerun on it (``pcvfe replay``).

Ports: ``actuation`` in (accepted, not used: a recording cannot be steered); ``state``,
``image``, ``station_status`` (constant, source ``replay``) out, ``true_mu``,
``true_terrain`` and ``true_state`` where the log has them, and the replay-only
``logged_actuation``: the input recorded with the drive, which ``MakeSimulation`` feeds to the
fitter and the log instead of the NMPC's command, and ``logged_features`` where the log holds
the features of every camera frame (a run folder: the drive log's ``f_00``... columns), which
``MakeSimulation`` feeds to the clustering instead of features computed from the saved images
(a run saves only some of its frames).
"""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource

from pcvfe_drake.hardware.replay import ReplayLog
from pcvfe_drake.hardware.watchdog import StationStatus
from pcvfe_drake.runs.scenario import Scenario
from pcvfe_drake.systems.drive_log_player import DriveLogPlayer


def MakeReplayStation(scenario: Scenario, log: ReplayLog) -> Diagram:
    """The replay station of ``log`` (named ``vehicle_station``; subsystems ``player`` and
    ``status``); ``scenario`` gives the camera size of the blank frame before the first."""
    builder = DiagramBuilder()
    logged = log.logged_feature_frames(scenario.rates.camera_period_s) is not None
    player = builder.AddNamedSystem(
        "player",
        DriveLogPlayer(
            log,
            width_px=scenario.camera.width_px,
            height_px=scenario.camera.height_px,
            logged_features=logged,
        ),
    )
    status = builder.AddNamedSystem(
        "status", ConstantValueSource(AbstractValue.Make(StationStatus(source="replay")))
    )
    builder.ExportInput(player.GetInputPort("actuation"), "actuation")
    for name in ("state", "image", "logged_actuation"):
        builder.ExportOutput(player.GetOutputPort(name), name)
    builder.ExportOutput(status.get_output_port(), "station_status")
    if log.has_truth:
        builder.ExportOutput(player.GetOutputPort("true_mu"), "true_mu")
        builder.ExportOutput(player.GetOutputPort("true_terrain"), "true_terrain")
    if logged:
        builder.ExportOutput(player.GetOutputPort("features"), "logged_features")
    if log.true_states is not None:
        builder.ExportOutput(player.GetOutputPort("true_state"), "true_state")
    diagram = builder.Build()
    diagram.set_name("vehicle_station")
    return diagram
