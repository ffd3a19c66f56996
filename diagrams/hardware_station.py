"""The hardware vehicle station: the real car (or ``pcvfe vehicle-bridge``) over LCM.

``MakeLcmStation`` (called by ``MakeVehicleStation(scenario, meshcat, hardware=True)``)
builds the station the way ``manipulation``'s hardware station does: LCM buses from the
scenario's ``hardware.lcm_buses`` (``diagrams/lcm_buses.py``), an ``LcmPublisherSystem`` for
the actuation, and small translator systems between LCM messages and the station's ports.
The two sensor channels are subscribed into ``MessageQueue`` s (``=>``) instead of
``LcmSubscriberSystem`` s, which hold only the newest message: the receivers drain and check
every message (``pcvfe_drake.hardware.playout``; ``hardware.playout_hold_s`` > 0 also replays
a stall's messages one per tick)::

    PCVFE_STATE     => state queue  -> state_receiver  --state-------------> (state)
    PCVFE_IMAGE     => image queue  -> camera_receiver --image-------------> (image)
    (actuation) -> actuation_sender -> actuation_publisher -> PCVFE_ACTUATION
    state_receiver.status, camera_receiver.status -> status_monitor ----> (station_status)

Exported ports: ``actuation`` in; ``state``, ``image``, ``station_status`` out: those of the
simulated station minus its sim-only truth. The receivers' watchdogs and what the station does
on each fault are described in ``docs/hardware.md``.

Initialization waits up to ``hardware.first_message_timeout_s`` (wall clock) for the first
state message and raises naming the channel and URL if none comes.

The receivers call the bus's ``HandleSubscriptions`` at each check, so a message that arrived
while the simulator slept to keep pace is taken at that check rather than the next.

The actuation is published at the NMPC's rate (``rates.nmpc_period_s``), ``publish_offset``
one fifth of the watchdog period after each NMPC update, so each command leaves right after it
is computed. The caller paces the simulator to wall-clock time (``hardware.realtime_rate``).
"""

from __future__ import annotations

from pydrake.geometry import Meshcat
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.lcm import LcmBuses, LcmPublisherSystem

from pcvfe_drake.diagrams.lcm_buses import scenario_lcm
from pcvfe_drake.hardware.playout import MessageQueue
from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation
from pcvfe_drake.runs.scenario import Scenario
from pcvfe_drake.systems.actuation_sender import ActuationSender
from pcvfe_drake.systems.camera_receiver import CameraReceiver
from pcvfe_drake.systems.station_status_monitor import StationStatusMonitor
from pcvfe_drake.systems.vehicle_state_receiver import VehicleStateReceiver

QUEUE_SECONDS = 2.0
"""How many seconds of messages a receiver's queue keeps between two checks."""


def queue_capacity(period_s: float) -> int:
    """Messages of a stream with period ``period_s`` in ``QUEUE_SECONDS`` (at least 5)."""
    return max(5, int(round(QUEUE_SECONDS / period_s)))


def MakeLcmStation(
    scenario: Scenario,
    meshcat: Meshcat | None = None,
    *,
    lcm_buses: LcmBuses | None = None,
) -> Diagram:
    """The LCM station of ``scenario`` (named ``vehicle_station``).

    Args:
        scenario: its ``hardware`` settings (buses, channels, watchdog limits), ``rates``
            (NMPC and camera periods) and ``camera`` (frame size of the blank frame).
        meshcat: unused (same signature as the simulated station).
        lcm_buses: already made buses (default: the scenario's, one ``DrakeLcm`` per URL and
            process: ``diagrams/lcm_buses.py``).

    Subsystems: ``state_receiver``, ``camera_receiver``, ``actuation_sender``,
    ``actuation_publisher``, ``status_monitor`` and ``lcm_interface`` (the
    ``LcmInterfaceSystem`` that pumps the bus).
    """
    hw = scenario.hardware
    builder = DiagramBuilder()
    lcm = scenario_lcm(hw, builder, lcm_buses, "MakeLcmStation")
    nmpc_period = scenario.rates.nmpc_period_s

    # Every message, not only the newest (playout.py): the receivers drain these queues.
    # Bounded to QUEUE_SECONDS of messages: a backlog older than that is late anyway.
    state_queue = MessageQueue(queue_capacity(hw.state_period_s))
    image_queue = MessageQueue(queue_capacity(scenario.rates.camera_period_s))
    lcm.Subscribe(hw.state_channel, state_queue.push)
    lcm.Subscribe(hw.image_channel, image_queue.push)
    wall_clock = hw.lateness_clock == "wall"
    url = lcm.get_lcm_url()
    state_rx = builder.AddNamedSystem(
        "state_receiver",
        VehicleStateReceiver(
            queue=state_queue,
            period_s=hw.watchdog_period_s,
            timeout_s=hw.state_timeout_s,
            max_delay_s=hw.state_max_delay_s,
            wall_clock=wall_clock,
            rate=hw.realtime_rate,
            max_hold_s=hw.playout_hold_s,
            first_message_timeout_s=hw.first_message_timeout_s,
            pump=lcm.HandleSubscriptions,
            source=f"channel {hw.state_channel} of {url}",
        ),
    )

    camera = scenario.camera
    camera_rx = builder.AddNamedSystem(
        "camera_receiver",
        CameraReceiver(
            queue=image_queue,
            width_px=camera.width_px,
            height_px=camera.height_px,
            period_s=hw.watchdog_period_s,
            timeout_s=hw.image_timeout_s,
            max_delay_s=hw.image_max_delay_s,
            wall_clock=wall_clock,
            rate=hw.realtime_rate,
            max_hold_s=hw.playout_hold_s,
            pump=lcm.HandleSubscriptions,
        ),
    )

    sender = builder.AddNamedSystem("actuation_sender", ActuationSender())
    publisher = builder.AddNamedSystem(
        "actuation_publisher",
        LcmPublisherSystem.Make(
            channel=hw.actuation_channel,
            lcm_type=lcmt_vehicle_actuation,
            lcm=lcm,
            publish_period=nmpc_period,
            publish_offset=hw.watchdog_period_s / 5.0,
        ),
    )
    builder.Connect(state_rx.GetOutputPort("state_utime"), sender.GetInputPort("state_utime"))
    builder.Connect(sender.GetOutputPort("message"), publisher.get_input_port())

    monitor = builder.AddNamedSystem(
        "status_monitor",
        StationStatusMonitor(
            state_timeout_s=hw.state_timeout_s, camera_timeout_s=hw.image_timeout_s
        ),
    )
    builder.Connect(state_rx.GetOutputPort("status"), monitor.GetInputPort("state_status"))
    builder.Connect(camera_rx.GetOutputPort("status"), monitor.GetInputPort("camera_status"))

    builder.ExportInput(sender.GetInputPort("actuation"), "actuation")
    builder.ExportOutput(state_rx.GetOutputPort("state"), "state")
    builder.ExportOutput(camera_rx.GetOutputPort("image"), "image")
    builder.ExportOutput(monitor.GetOutputPort("station_status"), "station_status")
    diagram = builder.Build()
    diagram.set_name("vehicle_station")
    return diagram
