"""The LCM station: the simulated station's ports, end to end against the vehicle bridge in one
process (memq://), and the safe behaviour when the state stream stops."""

import gc
import os

import numpy as np
import pytest
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import LcmBuses

from pcvfe_drake.control.course import initial_state
from pcvfe_drake.diagrams.station import (
    SIM_ONLY_OUTPUTS,
    STATION_INPUTS,
    STATION_OUTPUTS,
    MakeVehicleStation,
)
from pcvfe_drake.diagrams.vehicle_bridge import MakeVehicleBridge
from pcvfe_drake.diagrams.world_io import scenario_course
from pcvfe_drake.hardware.settings import LcmBusSettings
from pcvfe_drake.hardware.tcpq_hub import HubProcess
from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation, lcmt_vehicle_state
from pcvfe_drake.runs.scenario import Scenario
from pcvfe_drake.systems.nmpc import Nmpc
from pcvfe_drake.vehicle.params import load_vehicle


def memq_scenario() -> Scenario:
    scenario = Scenario(duration_s=2.0, laps=None)
    scenario.hardware.lcm_buses = {"default": LcmBusSettings(lcm_url="memq://")}
    scenario.hardware.first_message_timeout_s = 0.0  # the messages come from the test itself
    scenario.hardware.lateness_clock = "sim"  # one process, faster than real time
    return scenario


def shared_buses():
    lcm = DrakeLcm("memq://")
    buses = LcmBuses()
    buses.Add("default", lcm)
    return lcm, buses


def port_names(system, kind):
    n = getattr(system, f"num_{kind}_ports")()
    return {getattr(system, f"get_{kind}_port")(i).get_name() for i in range(n)}


def test_hardware_station_exports_the_simulated_ports_without_the_sim_only_ones():
    scenario = memq_scenario()
    hardware = MakeVehicleStation(scenario, hardware=True)  # its own memq bus
    sim = MakeVehicleStation(scenario)
    assert hardware.get_name() == sim.get_name() == "vehicle_station"
    assert port_names(hardware, "input") == port_names(sim, "input") == set(STATION_INPUTS)
    assert port_names(hardware, "output") == set(STATION_OUTPUTS)
    assert port_names(sim, "output") == set(STATION_OUTPUTS) | set(SIM_ONLY_OUTPUTS)
    assert all(s.get_name() for s in hardware.GetSystems())


def test_station_against_the_bridge_in_one_process_sees_the_vehicle():
    scenario = memq_scenario()
    lcm, buses = shared_buses()
    builder = DiagramBuilder()
    station = builder.AddNamedSystem(
        "station", MakeVehicleStation(scenario, hardware=True, lcm_buses=buses)
    )
    bridge = builder.AddNamedSystem("bridge", MakeVehicleBridge(scenario, lcm_buses=buses))
    diagram = builder.Build()
    commands = []
    lcm.Subscribe(
        scenario.hardware.actuation_channel,
        lambda data: commands.append(lcmt_vehicle_actuation.decode(data)),
    )
    simulator = Simulator(diagram)
    ctx = simulator.get_mutable_context()
    st_ctx = station.GetMyMutableContextFromRoot(ctx)
    station.GetInputPort("actuation").FixValue(st_ctx, [0.0, 0.5])
    simulator.AdvanceTo(1.0)
    br_ctx = bridge.GetMyContextFromRoot(ctx)
    truth = bridge.GetOutputPort("true_state").Eval(br_ctx)
    seen = station.GetOutputPort("state").Eval(st_ctx)
    # The station's state is at most two state periods old (a message published at t is taken
    # at the next check, 10 ms later, as checks at t see the subscriber before its update).
    assert np.linalg.norm(seen[:2] - truth[:2]) < 0.0201 * truth[3]
    # The car accelerates at the commanded 0.5 m/s^2 (from 3 m/s), so the commands arrive.
    assert 3.4 < truth[3] < 3.5
    status = station.GetOutputPort("station_status").Eval(st_ctx)
    assert status.ok and status.source == "lcm"
    counts = status.to_dict()["streams"]
    assert counts["state"]["accepted"] >= 95 and counts["camera"]["accepted"] >= 9
    image = np.asarray(station.GetOutputPort("image").Eval(st_ctx).data)
    assert image.shape == (224, 224, 4) and image[:, :, :3].std() > 5
    # The actuation goes out at the NMPC's rate with the state timestamp it followed.
    assert 19 <= len(commands) <= 21
    assert all(c.accel == 0.5 for c in commands)
    lag_us = [c.utime - c.state_utime for c in commands[1:]]
    assert max(lag_us) <= 20_000


def test_state_loss_makes_the_nmpc_brake_and_the_status_say_why():
    scenario = memq_scenario()
    lcm, buses = shared_buses()
    params = load_vehicle(scenario.vehicle)
    course = scenario_course(scenario)
    builder = DiagramBuilder()
    station = builder.AddNamedSystem(
        "station", MakeVehicleStation(scenario, hardware=True, lcm_buses=buses)
    )
    nmpc = builder.AddNamedSystem(
        "nmpc", Nmpc(course, params, scenario.nmpc_config(), fixed_theta=params.theta)
    )
    builder.Connect(station.GetOutputPort("state"), nmpc.GetInputPort("state"))
    builder.Connect(nmpc.GetOutputPort("actuation"), station.GetInputPort("actuation"))
    diagram = builder.Build()
    commands = []
    lcm.Subscribe(
        scenario.hardware.actuation_channel,
        lambda data: commands.append(lcmt_vehicle_actuation.decode(data)),
    )
    simulator = Simulator(diagram)
    ctx = simulator.get_mutable_context()
    x = initial_state(course, params, 3.0)
    t = 0.0
    while t < 0.5 - 1e-9:  # a car standing still at 3 m/s would say this at 100 Hz
        msg = lcmt_vehicle_state()
        msg.utime, msg.state, msg.valid = int(round(t * 1e6)), list(map(float, x)), True
        lcm.Publish(scenario.hardware.state_channel, msg.encode())
        t += 0.01
        simulator.AdvanceTo(t)
    nmpc_ctx = nmpc.GetMyContextFromRoot(ctx)
    assert nmpc.GetOutputPort("diagnostics").Eval(nmpc_ctx).mode == "qp"
    simulator.AdvanceTo(2.0)  # no more state messages
    st_ctx = station.GetMyContextFromRoot(ctx)
    assert np.all(np.isnan(station.GetOutputPort("state").Eval(st_ctx)))
    status = station.GetOutputPort("station_status").Eval(st_ctx)
    assert status.state == "timeout" and status.reason().startswith("state timeout")
    diag = nmpc.GetOutputPort("diagnostics").Eval(nmpc_ctx)
    assert diag.mode == "braking" and diag.status == "state not finite"
    last = commands[-1]
    assert last.steer_rate == 0.0 and last.accel < -1.0
    assert last.state_utime == 490_000  # the last state it had


def test_a_scenario_bus_that_does_not_exist_is_named():
    scenario = memq_scenario()
    scenario.hardware.bus = "car"
    _, buses = shared_buses()
    with pytest.raises(ValueError, match="hardware.bus='car'"):
        MakeVehicleStation(scenario, hardware=True, lcm_buses=buses)


def test_bridge_logs_the_plants_true_state():
    scenario = memq_scenario()
    _, buses = shared_buses()
    bridge = MakeVehicleBridge(scenario, lcm_buses=buses)
    inner = bridge.GetSubsystemByName("station")
    ctx = bridge.CreateDefaultContext()
    truth = bridge.GetOutputPort("true_state").Eval(ctx)
    np.testing.assert_array_equal(
        truth, inner.GetOutputPort("true_state").Eval(inner.GetMyContextFromRoot(ctx))
    )


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="counts /proc/self/fd (Linux)")
def test_building_many_stations_on_one_url_does_not_leak_sockets():
    # pydrake never frees a diagram holding Python systems, so each station used to keep its
    # own DrakeLcm (a socket) for the life of the process; past 1024 descriptors the LCM C
    # library aborts in select(). One DrakeLcm per URL and process keeps the count flat.
    with HubProcess(port=0) as hub:
        scenario = memq_scenario()
        scenario.hardware.lcm_buses = {"default": LcmBusSettings(lcm_url=hub.url)}
        counts = []
        for _ in range(8):
            station = MakeVehicleStation(scenario, hardware=True)
            simulator = Simulator(station)
            station.GetInputPort("actuation").FixValue(simulator.get_mutable_context(), [0, 0])
            simulator.AdvanceTo(0.05)
            del simulator, station
            gc.collect()
            counts.append(open_fds())
        assert counts[-1] == counts[0], counts
