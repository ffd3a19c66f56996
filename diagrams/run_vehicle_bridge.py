"""Running the vehicle bridge: the simulated car behind LCM, paced to wall-clock time.

:func:`run_vehicle_bridge` builds ``MakeVehicleBridge`` on the scenario's bus, logs the truth
(state, mu, terrain: what the car really did) and measures the latency from each state message
to the actuation computed after it (``pcvfe_drake.hardware.latency``), until the duration is
reached, the hardware station has been silent for ``idle_stop_s``, the simulated truth ends
(the multi-body model's singularity: the car reversed or spun, ``MbSingularity``), or Ctrl-C.

Start: like a car on a test rig, the bridged car does not move before the controller is up.
:func:`hold_until_first_command` publishes the car's initial state, standing still in time, at
the state rate, and pumps the bus, until the station's first actuation command arrives
(``hardware.first_command_timeout_s`` at most, else an error naming the channel and URL). The
simulator then starts at that moment: its clock counts the wall time waited (the held states'
time stamps keep rising, so the station's watchdog sees neither duplicates nor a jump back) but
the plant is integrated only from there, with the command already received, and the duration
counts from there. A station that boots for seconds thus finds the car as the scenario starts
it, not braked by the vehicle's watchdog to a crawl (which the station's first commands, held
while states arrived late, then turned into reversing).

Before it holds, :func:`warm_up` computes once, on a throwaway context, what the first step
computes (the plant's derivatives or discrete update, the state and camera messages): a
process's first call of the compiled tyre model loads numba's machinery and the first frame is
rendered from scratch, about a second together. Paid after the hold, that second stalls the
car's clock: its state stamps fall behind the held ones by it and catch up only as fast as the
bridge can run ahead of real time, and the station's watchdog, which judges each delay against
the smallest seen, rejects every state as ``late`` until they do.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from pydrake.lcm import DrakeLcmParams
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import LcmBuses
from pydrake.systems.primitives import LogVectorOutput

from pcvfe_drake.diagrams.lcm_buses import shared_drake_lcm
from pcvfe_drake.diagrams.vehicle_bridge import MakeVehicleBridge
from pcvfe_drake.diagrams.warm_up import warm_up
from pcvfe_drake.diagrams.world_io import scenario_world
from pcvfe_drake.hardware.latency import LatencyRecorder
from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation, lcmt_vehicle_state
from pcvfe_drake.runs.scenario import Scenario
from pcvfe_drake.vehicle.mb_truth import MbSingularity
from pcvfe_drake.vehicle.single_track import STATE_NAMES

TRUTH_PERIOD_S = 0.05
"""Period of the truth log rows [s]."""


@dataclass
class BridgeResult:
    sim_time_s: float
    wall_time_s: float
    latency: dict
    actuation_status: dict
    truth: pd.DataFrame
    stopped_because: str
    started_s: float = 0.0
    """The bridge's time [s] at which the first command came and the car started (the wall
    time it waited, on the simulated clock); ``sim_time_s`` counts from 0, the driving from
    here."""

    def to_dict(self) -> dict:
        return {
            "sim_time_s": self.sim_time_s,
            "started_s": self.started_s,
            "wall_time_s": self.wall_time_s,
            "realtime_factor": self.sim_time_s / self.wall_time_s if self.wall_time_s else None,
            "latency": self.latency,
            "actuation": self.actuation_status,
            "stopped_because": self.stopped_because,
        }


def run_vehicle_bridge(
    scenario: Scenario,
    *,
    duration_s: float,
    out_dir: Path | None = None,
    realtime_rate: float | None = None,
    idle_stop_s: float | None = None,
    chunk_s: float = 0.5,
    progress=None,
    lcm=None,
) -> BridgeResult:
    """Hold the car until the first command (module docstring), then run the bridge for
    ``duration_s`` simulated seconds of driving at ``realtime_rate`` (default the scenario's
    ``hardware.realtime_rate``); stop early once actuation has been received and then nothing
    more for ``idle_stop_s`` wall seconds (the station finished). Writes ``truth.csv`` and
    ``bridge.json`` into ``out_dir`` when given. ``progress(t_driving_s, recorder)`` is called
    after each chunk; ``lcm``: an already made ``DrakeLcm`` of the scenario's bus (tests share a
    ``memq://`` one), default :func:`shared_drake_lcm`. Raises RuntimeError when no command
    comes within ``hardware.first_command_timeout_s``."""
    hw = scenario.hardware
    bus = hw.lcm_buses[hw.bus]
    if lcm is None:
        params = DrakeLcmParams(lcm_url=bus.lcm_url, channel_suffix=bus.channel_suffix)
        lcm = shared_drake_lcm(params)
    buses = LcmBuses()
    buses.Add(hw.bus, lcm)
    recorder = LatencyRecorder()
    last_actuation_wall = [None]

    def on_state(data: bytes) -> None:
        recorder.note_state(lcmt_vehicle_state.decode(data).utime, time.perf_counter())

    def on_actuation(data: bytes) -> None:
        now = time.perf_counter()
        last_actuation_wall[0] = now
        recorder.note_actuation(lcmt_vehicle_actuation.decode(data).state_utime, now)

    # Raw subscriptions on the bridge's own bus: its LcmInterfaceSystem dispatches them too.
    lcm.Subscribe(hw.state_channel, on_state)
    lcm.Subscribe(hw.actuation_channel, on_actuation)

    builder = DiagramBuilder()
    bridge = builder.AddNamedSystem("bridge", MakeVehicleBridge(scenario, lcm_buses=buses))
    sinks = {}
    for name in ("true_state", "true_mu", "true_terrain"):
        sinks[name] = LogVectorOutput(
            bridge.GetOutputPort(name), builder, publish_period=TRUTH_PERIOD_S
        )
        sinks[name].set_name(f"log_{name}")
    diagram = builder.Build()
    diagram.set_name("vehicle_bridge_run")
    simulator = Simulator(diagram)
    simulator.set_target_realtime_rate(hw.realtime_rate if realtime_rate is None else realtime_rate)
    warm_up(diagram)
    stopped = "duration"
    w0 = time.perf_counter()
    start = 0.0
    try:
        start = hold_until_first_command(
            simulator,
            diagram.GetSubsystemByName("bridge").GetSubsystemByName("state_publisher"),
            lcm,
            lambda: last_actuation_wall[0] is not None,
            hw,
        )
        simulator.Initialize()
        t, end = start, start + duration_s
        while t < end - 1e-9:
            simulator.AdvanceTo(min(t + chunk_s, end))
            t = simulator.get_context().get_time()
            if progress is not None:
                progress(t - start, recorder)
            quiet = last_actuation_wall[0]
            if idle_stop_s is not None and quiet is not None:
                if time.perf_counter() - quiet > idle_stop_s:
                    stopped = "station silent"
                    break
    except KeyboardInterrupt:
        stopped = "interrupted"
    except MbSingularity as exc:  # the car reversed or spun out of the multi-body truth
        stopped = f"truth_singular: {exc}"
    wall = time.perf_counter() - w0
    context = simulator.get_context()
    status = bridge.GetOutputPort("actuation_status").Eval(bridge.GetMyContextFromRoot(context))
    truth = _truth_frame(scenario, {k: s.FindLog(context) for k, s in sinks.items()})
    result = BridgeResult(
        sim_time_s=context.get_time(),
        wall_time_s=wall,
        latency=recorder.summary(),
        actuation_status=status.to_dict(),
        truth=truth,
        stopped_because=stopped,
        started_s=start,
    )
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        truth.to_csv(out_dir / "truth.csv", index=False)
        (out_dir / "bridge.json").write_text(json.dumps(result.to_dict(), indent=2))
    return result


def hold_until_first_command(
    simulator: Simulator,
    state_publisher,
    lcm,
    heard: Callable[[], bool],
    hw,
    clock: Callable[[], float] = time.monotonic,
) -> float:
    """Before ``simulator`` is initialized: publish the car's initial state every
    ``hw.state_period_s`` of wall time through ``state_publisher`` (the bridge's
    ``LcmPublisherSystem``), each stamped with the time waited, and pump ``lcm`` until
    ``heard()`` says the first actuation command arrived. Returns the simulated start time [s]:
    the wall time waited (at least the next state tick after the last held message), rounded up
    to the grid of the watchdog period (so the vehicle's actuation check runs at the start and
    takes the command at once). The context's
    time is set to it; nothing is integrated before it. Raises RuntimeError after
    ``hw.first_command_timeout_s`` (wall clock)."""
    context = simulator.get_mutable_context()
    publisher_context = state_publisher.GetMyContextFromRoot(context)
    period = hw.state_period_s
    w0 = clock()
    held = 0  # messages published so far (the next is stamped held * period)
    while not heard():
        waited = clock() - w0
        if waited > hw.first_command_timeout_s:
            url = hw.lcm_buses[hw.bus].lcm_url
            raise RuntimeError(
                f"vehicle bridge: no actuation command on {hw.actuation_channel} at {url} within "
                f"{hw.first_command_timeout_s:g} s (hardware.first_command_timeout_s); is the "
                "station (`pcvfe simulate --hardware`) running on that URL?"
            )
        if waited >= held * period:
            tick = int(waited // period)  # the latest state tick, also after a stall
            context.SetTime(tick * period)
            state_publisher.ForcedPublish(publisher_context)
            held = tick + 1
        lcm.HandleSubscriptions(max(1, int(1000 * (held * period - (clock() - w0)))))
    watchdog = hw.watchdog_period_s
    now = max(held * period, clock() - w0)
    start = math.ceil(now / watchdog - 1e-9) * watchdog
    context.SetTime(start)
    return start


def _truth_frame(scenario: Scenario, logs: dict) -> pd.DataFrame:
    names = scenario_world(scenario).terrain_map.names
    state = logs["true_state"]
    t = state.sample_times()
    frame = pd.DataFrame({"t": t})
    for i, name in enumerate(STATE_NAMES):
        frame[name] = state.data()[i]
    frame["mu_true"] = logs["true_mu"].data()[0]
    index = np.round(logs["true_terrain"].data()[0]).astype(int)
    frame["terrain"] = [names[k] if 0 <= k < len(names) else "" for k in index]
    return frame
