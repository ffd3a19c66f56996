"""The vehicle side of the LCM interface, simulated: ``pcvfe vehicle-bridge`` runs this diagram.

``MakeVehicleBridge`` puts the simulated station (plant + camera, ``station.py``) behind the same
LCM channels a real car would use, so the hardware station and the whole pipeline can be
rehearsed against it in another process (hardware-in-the-loop rehearsal)::

    station.state -> state_sender -> state_publisher ------------------------> PCVFE_STATE
    station.image -> image_encoder -> image_publisher -----------------------> PCVFE_IMAGE
    PCVFE_ACTUATION -> actuation_subscriber -> actuation_receiver -> station.actuation

The ``actuation_receiver`` brakes the car when commands stop arriving (a real car's low-level
controller does the same). The state it publishes is the simulated station's ``state``: what
the car's sensors report under the scenario's ``sensing``. Exported outputs: ``true_state``
(the plant's state), ``true_mu``,
``true_terrain`` (the truth, for the bridge's own log) and ``actuation_status``.
"""

from __future__ import annotations

from drake import lcmt_image_array
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.lcm import LcmBuses, LcmPublisherSystem, LcmSubscriberSystem
from pydrake.systems.sensors import ImageToLcmImageArrayT, PixelType

from pcvfe_drake.diagrams.lcm_buses import scenario_lcm
from pcvfe_drake.diagrams.station import MakeVehicleStation
from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation, lcmt_vehicle_state
from pcvfe_drake.runs.scenario import Scenario
from pcvfe_drake.systems.actuation_receiver import ActuationReceiver
from pcvfe_drake.systems.vehicle_state_sender import VehicleStateSender

IMAGE_PUBLISH_DELAY_S = 0.001
"""The camera frame taken at t is published at t + this (after the frame is rendered)."""


def MakeVehicleBridge(scenario: Scenario, *, lcm_buses: LcmBuses | None = None) -> Diagram:
    """The simulated vehicle behind LCM (named ``vehicle_bridge``).

    Args:
        scenario: the simulated vehicle (as for ``MakeVehicleStation``) and its ``hardware``
            settings (buses, channels, the state period, the actuation timeout and braking).
        lcm_buses: already made buses (default: ``ApplyLcmBusConfig`` from the scenario).
    """
    hw = scenario.hardware
    builder = DiagramBuilder()
    lcm = scenario_lcm(hw, builder, lcm_buses, "MakeVehicleBridge")
    station = builder.AddNamedSystem("station", MakeVehicleStation(scenario))

    state_sender = builder.AddNamedSystem("state_sender", VehicleStateSender())
    state_publisher = builder.AddNamedSystem(
        "state_publisher",
        LcmPublisherSystem.Make(
            channel=hw.state_channel,
            lcm_type=lcmt_vehicle_state,
            lcm=lcm,
            publish_period=hw.state_period_s,
        ),
    )
    builder.Connect(station.GetOutputPort("state"), state_sender.GetInputPort("state"))
    builder.Connect(state_sender.GetOutputPort("message"), state_publisher.get_input_port())

    encoder = builder.AddNamedSystem("image_encoder", ImageToLcmImageArrayT(do_compress=False))
    color = encoder.DeclareImageInputPort[PixelType.kRgba8U]("color")
    image_publisher = builder.AddNamedSystem(
        "image_publisher",
        LcmPublisherSystem.Make(
            channel=hw.image_channel,
            lcm_type=lcmt_image_array,
            lcm=lcm,
            publish_period=scenario.rates.camera_period_s,
            use_cpp_serializer=True,
            publish_offset=IMAGE_PUBLISH_DELAY_S,
        ),
    )
    builder.Connect(station.GetOutputPort("image"), color)
    builder.Connect(encoder.get_output_port(), image_publisher.get_input_port())

    actuation_subscriber = builder.AddNamedSystem(
        "actuation_subscriber",
        LcmSubscriberSystem.Make(
            channel=hw.actuation_channel, lcm_type=lcmt_vehicle_actuation, lcm=lcm
        ),
    )
    receiver = builder.AddNamedSystem(
        "actuation_receiver",
        ActuationReceiver(
            period_s=hw.watchdog_period_s,
            timeout_s=hw.actuation_timeout_s,
            brake_decel_mps2=hw.brake_decel_mps2,
        ),
    )
    builder.Connect(actuation_subscriber.get_output_port(), receiver.GetInputPort("message"))
    builder.Connect(station.GetOutputPort("state"), receiver.GetInputPort("state"))
    builder.Connect(receiver.GetOutputPort("actuation"), station.GetInputPort("actuation"))

    # The station's `state` is what the car's sensors report (the scenario's sensing); the log of
    # what the car really did is its sim-only true state.
    builder.ExportOutput(station.GetOutputPort("true_state"), "true_state")
    builder.ExportOutput(station.GetOutputPort("true_mu"), "true_mu")
    builder.ExportOutput(station.GetOutputPort("true_terrain"), "true_terrain")
    builder.ExportOutput(receiver.GetOutputPort("status"), "actuation_status")
    diagram = builder.Build()
    diagram.set_name("vehicle_bridge")
    return diagram
