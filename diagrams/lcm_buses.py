"""The scenario's LCM buses as Drake ``LcmBuses`` (``ApplyLcmBusConfig``), shared by the
hardware station and the vehicle bridge."""

from __future__ import annotations

from pydrake.lcm import DrakeLcmInterface, DrakeLcmParams
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import ApplyLcmBusConfig, LcmBuses, LcmInterfaceSystem

from pcvfe_drake.hardware.settings import HardwareSettings


def lcm_bus_params(settings: HardwareSettings) -> dict[str, DrakeLcmParams]:
    """``hardware.lcm_buses`` as ``DrakeLcmParams`` by bus name."""
    return {
        name: DrakeLcmParams(lcm_url=bus.lcm_url, channel_suffix=bus.channel_suffix)
        for name, bus in settings.lcm_buses.items()
    }


def scenario_lcm(
    settings: HardwareSettings, builder: DiagramBuilder, lcm_buses: LcmBuses | None, who: str
) -> DrakeLcmInterface:
    """The ``DrakeLcm`` of ``settings.bus``: from ``lcm_buses`` when given (tests share one
    ``memq://`` instance between two diagrams), else made by ``ApplyLcmBusConfig``, which also
    adds the ``LcmInterfaceSystem`` that pumps the bus while the diagram runs (for given
    buses this adds one for the bus used, named ``lcm_interface``)."""
    made_here = lcm_buses is None
    if made_here:
        lcm_buses = ApplyLcmBusConfig(lcm_buses=lcm_bus_params(settings), builder=builder)
    if settings.bus not in lcm_buses.GetAllBusNames():
        raise ValueError(
            f"{who}: hardware.bus={settings.bus!r} is not one of the LCM buses "
            f"{lcm_buses.GetAllBusNames()}"
        )
    lcm = lcm_buses.Find(who, settings.bus)
    if not made_here:
        builder.AddNamedSystem("lcm_interface", LcmInterfaceSystem(lcm))
    return lcm
