"""Running the vehicle bridge: the simulated car behind LCM, paced to wall-clock time.

:func:`run_vehicle_bridge` builds ``MakeVehicleBridge`` on the scenario's bus, logs the truth
(state, mu, terrain: what the car really did) and measures the latency from each state message
to the actuation computed after it (``pcvfe_drake.hardware.latency``), until the duration is
reached, the hardware station has been silent for ``idle_stop_s``, or Ctrl-C.
"""

from __future__ import annotations

import json
import time
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
from pcvfe_drake.diagrams.world_io import scenario_world
from pcvfe_drake.hardware.latency import LatencyRecorder
from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation, lcmt_vehicle_state
from pcvfe_drake.runs.scenario import Scenario
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

    def to_dict(self) -> dict:
        return {
            "sim_time_s": self.sim_time_s,
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
) -> BridgeResult:
    """Run the bridge for ``duration_s`` simulated seconds at ``realtime_rate`` (default the
    scenario's ``hardware.realtime_rate``); stop early once actuation has been received and then
    nothing more for ``idle_stop_s`` wall seconds (the station finished). Writes
    ``truth.csv`` and ``bridge.json`` into ``out_dir`` when given."""
    hw = scenario.hardware
    bus = hw.lcm_buses[hw.bus]
    lcm = shared_drake_lcm(DrakeLcmParams(lcm_url=bus.lcm_url, channel_suffix=bus.channel_suffix))
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
    stopped = "duration"
    w0 = time.perf_counter()
    try:
        simulator.Initialize()
        t = 0.0
        while t < duration_s - 1e-9:
            simulator.AdvanceTo(min(t + chunk_s, duration_s))
            t = simulator.get_context().get_time()
            if progress is not None:
                progress(t, recorder)
            quiet = last_actuation_wall[0]
            if idle_stop_s is not None and quiet is not None:
                if time.perf_counter() - quiet > idle_stop_s:
                    stopped = "station silent"
                    break
    except KeyboardInterrupt:
        stopped = "interrupted"
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
    )
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        truth.to_csv(out_dir / "truth.csv", index=False)
        (out_dir / "bridge.json").write_text(json.dumps(result.to_dict(), indent=2))
    return result


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
