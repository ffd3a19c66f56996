"""The scenario's LCM buses as Drake ``LcmBuses``, shared by the hardware station and the vehicle
bridge.

One ``DrakeLcm`` per URL and process (:func:`shared_drake_lcm`). A diagram that holds Python
``LeafSystem`` s is never freed by pydrake (the C++ diagram and the Python systems keep each
other alive), so each station or bridge built in a process used to keep its own ``DrakeLcm``,
and with it a socket, for the life of the process: a process that builds a few hundred of them
(a test session, a notebook) runs past ``FD_SETSIZE`` (1024) and the LCM C library aborts in
``select()`` ("bit out of range 0 - FD_SETSIZE"). Sharing the instance per URL keeps it at one
socket per URL. ``memq://`` instances open no file descriptor and stay separate (each one is
its own in-process bus, which the tests rely on).
"""

from __future__ import annotations

import threading

from pydrake.lcm import DrakeLcm, DrakeLcmInterface, DrakeLcmParams
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import LcmBuses, LcmInterfaceSystem

from pcvfe_drake.hardware.settings import HardwareSettings

_SHARED: dict[tuple[str, str], DrakeLcm] = {}
_SHARED_LOCK = threading.Lock()


def lcm_bus_params(settings: HardwareSettings) -> dict[str, DrakeLcmParams]:
    """``hardware.lcm_buses`` as ``DrakeLcmParams`` by bus name."""
    return {
        name: DrakeLcmParams(lcm_url=bus.lcm_url, channel_suffix=bus.channel_suffix)
        for name, bus in settings.lcm_buses.items()
    }


def shared_drake_lcm(params: DrakeLcmParams) -> DrakeLcm:
    """The process's ``DrakeLcm`` for ``params`` (a new one for ``memq://``)."""
    if params.lcm_url.startswith("memq://"):
        return DrakeLcm(params)
    key = (params.lcm_url, params.channel_suffix)
    with _SHARED_LOCK:
        lcm = _SHARED.get(key)
        if lcm is None:
            lcm = _SHARED[key] = DrakeLcm(params)
        return lcm


def scenario_buses(settings: HardwareSettings) -> LcmBuses:
    """``LcmBuses`` of ``hardware.lcm_buses`` (as ``ApplyLcmBusConfig`` makes them, but with
    :func:`shared_drake_lcm` instances)."""
    buses = LcmBuses()
    for name, params in lcm_bus_params(settings).items():
        buses.Add(name, shared_drake_lcm(params))
    return buses


def scenario_lcm(
    settings: HardwareSettings, builder: DiagramBuilder, lcm_buses: LcmBuses | None, who: str
) -> DrakeLcmInterface:
    """The ``DrakeLcm`` of ``settings.bus``, from ``lcm_buses`` when given (tests share one
    ``memq://`` instance between two diagrams), else from :func:`scenario_buses`; adds the
    ``LcmInterfaceSystem`` (named ``lcm_interface``) that pumps that bus while the diagram
    runs."""
    if lcm_buses is None:
        lcm_buses = scenario_buses(settings)
    if settings.bus not in lcm_buses.GetAllBusNames():
        raise ValueError(
            f"{who}: hardware.bus={settings.bus!r} is not one of the LCM buses "
            f"{lcm_buses.GetAllBusNames()}"
        )
    lcm = lcm_buses.Find(who, settings.bus)
    builder.AddNamedSystem("lcm_interface", LcmInterfaceSystem(lcm))
    return lcm
