"""Hardware settings of a scenario: LCM buses, channels, rates and watchdog limits.

Kept in the core (no pydrake) like the rest of the scenario; ``diagrams/hardware_station.py``
turns ``lcm_buses`` into ``pydrake.lcm.DrakeLcmParams`` for ``ApplyLcmBusConfig``.
This module does not use ``from __future__ import annotations`` (``yaml_load_typed`` reads the
field types).
"""

import dataclasses
import math
from dataclasses import dataclass, field

from pcvfe_drake.hardware.scheduling import priority_problem

LOCAL_HUB_URL = "tcpq://127.0.0.1:7700"
"""Default LCM URL: the localhost ``tcpq`` hub that ``pcvfe vehicle-bridge`` starts (no network
traffic leaves the machine). A real car on a LAN would use a ``udpm://`` URL instead."""


@dataclass
class LcmBusSettings:
    """One LCM bus (``pydrake.lcm.DrakeLcmParams``)."""

    lcm_url: str = LOCAL_HUB_URL
    channel_suffix: str = ""


@dataclass
class HardwareSettings:
    """How the hardware station (``MakeVehicleStation(..., hardware=True)``) and the vehicle
    bridge talk, and what the station's watchdog accepts. Periods and limits in seconds."""

    lcm_buses: dict[str, LcmBusSettings] = field(
        default_factory=lambda: {"default": LcmBusSettings()}
    )
    """LCM buses by name (as ``lcm_buses`` in ``manipulation``'s scenarios)."""
    bus: str = "default"
    """The bus every channel below uses."""
    state_channel: str = "PCVFE_STATE"
    actuation_channel: str = "PCVFE_ACTUATION"
    image_channel: str = "PCVFE_IMAGE"
    state_period_s: float = 0.01
    """Period of the vehicle's state messages (100 Hz, the platform's)."""
    watchdog_period_s: float = 0.01
    """Period at which the station's receivers check for new messages (100 Hz: the state rate,
    on the same ticks as the fitter's sampling, so the checks add no simulator steps)."""
    state_timeout_s: float = 0.05
    """No accepted state message for this long: the station's ``state`` becomes NaN (the NMPC's
    fallback: the last plan shifted, then braking) and ``station_status`` says ``timeout``."""
    state_max_delay_s: float = 0.05
    """A state message whose transport delay exceeds the smallest delay seen so far by more than
    this is rejected as ``late``."""
    lateness_clock: str = "wall"
    """Clock on which the receivers measure message delays: ``"wall"`` (hardware: a station
    that fell behind real time and catches up does not take fresh messages for late ones) or
    ``"sim"`` (the station's simulated time: deterministic, for tests in one process)."""
    playout_hold_s: float = 0.0
    """How long [s] the receivers may hold a message back so that a station running behind real
    time takes each message at its own tick (``pcvfe_drake.hardware.playout``): 0 hands out the
    newest message at every check (the NMPC steers on the freshest state; after a stall the
    fitter sees that state held over the late ticks); more replays a stall's messages one per
    tick but gives the NMPC states up to that much older while the station lags (measured in
    docs/hardware.md)."""
    image_timeout_s: float = 0.35
    """No accepted camera frame for this long: the station's ``image`` becomes blank (features
    NaN, context noise) and ``station_status`` says ``timeout``."""
    image_max_delay_s: float = 0.2
    """Like ``state_max_delay_s`` for camera frames."""
    actuation_timeout_s: float = 0.25
    """Vehicle side (bridge): no actuation for this long makes the vehicle brake."""
    brake_decel_mps2: float = 3.0
    """Vehicle side (bridge): braking deceleration when the actuation is lost [m/s^2]."""
    first_message_timeout_s: float = 10.0
    """The station's initialization waits this long (wall clock) for the first state message
    and fails with an error naming the channel and URL if none comes (0: do not wait)."""
    first_command_timeout_s: float = 120.0
    """Vehicle side (bridge): the car stands at its initial state, publishing it, until the
    station's first actuation command arrives (a test rig holds the car until the controller is
    up: a station that boots for seconds must not find the car already braked or rolling
    away); with none within this long (wall clock) the bridge stops with an error naming the
    channel and URL."""
    realtime_rate: float = 1.0
    """Simulated time per wall-clock second on hardware (1: paced to wall-clock time)."""
    control_priority: int = 0
    """Linux ``SCHED_FIFO`` priority (1-99; 0: off, ordinary scheduling) of the thread that runs
    the station's loop (receivers, NMPC, publishing) in ``pcvfe simulate --hardware``: a control
    loop must not wait for a core behind best-effort work on the same computer. The refit
    worker stays at ordinary priority, so a refit never preempts the loop. Needs root,
    CAP_SYS_NICE or an rtprio limit (docs/hardware.md); refused otherwise, at start-up."""


def hardware_problems(settings: HardwareSettings) -> list[str]:
    """Problems of ``settings`` as ``"hardware.field=value: reason"`` strings."""
    problems: list[str] = []
    if not settings.lcm_buses:
        problems.append("hardware.lcm_buses={}: needs at least one bus")
    for name, bus in settings.lcm_buses.items():
        if not isinstance(bus.lcm_url, str) or "://" not in bus.lcm_url:
            problems.append(
                f"hardware.lcm_buses.{name}.lcm_url={bus.lcm_url!r}: must be an LCM URL "
                "such as tcpq://127.0.0.1:7700, memq:// or udpm://239.255.76.67:7667"
            )
    if settings.bus not in settings.lcm_buses:
        problems.append(
            f"hardware.bus={settings.bus!r}: not one of hardware.lcm_buses "
            f"({', '.join(sorted(settings.lcm_buses))})"
        )
    channels = [settings.state_channel, settings.actuation_channel, settings.image_channel]
    for name, value in zip(("state", "actuation", "image"), channels, strict=True):
        if not (isinstance(value, str) and value.strip()):
            problems.append(f"hardware.{name}_channel={value!r}: must not be empty")
    if settings.lateness_clock not in ("wall", "sim"):
        problems.append(
            f"hardware.lateness_clock={settings.lateness_clock!r}: must be 'wall' or 'sim'"
        )
    if len(set(channels)) != len(channels):
        problems.append(f"hardware channels {channels}: must be three different names")
    priority = priority_problem(settings.control_priority, "hardware.control_priority")
    if priority:
        problems.append(priority)
    for f in dataclasses.fields(HardwareSettings):
        value = getattr(settings, f.name)
        if f.type is not float:
            continue
        least = 0.0 if f.name in ("first_message_timeout_s", "playout_hold_s") else None
        ok = isinstance(value, int | float) and math.isfinite(value)
        ok = ok and (value >= least if least is not None else value > 0)
        if not ok:
            bound = ">= 0" if least is not None else "> 0"
            problems.append(f"hardware.{f.name}={value!r}: must be a finite number {bound}")
    return problems
