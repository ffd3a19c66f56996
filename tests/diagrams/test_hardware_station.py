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
from pcvfe_drake.diagrams.run_vehicle_bridge import run_vehicle_bridge
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


def station_with_nmpc(scenario, buses):
    params = load_vehicle(scenario.vehicle)
    builder = DiagramBuilder()
    station = builder.AddNamedSystem(
        "station", MakeVehicleStation(scenario, hardware=True, lcm_buses=buses)
    )
    nmpc = builder.AddNamedSystem(
        "nmpc",
        Nmpc(scenario_course(scenario), params, scenario.nmpc_config(), fixed_theta=params.theta),
    )
    builder.Connect(station.GetOutputPort("state"), nmpc.GetInputPort("state"))
    builder.Connect(nmpc.GetOutputPort("actuation"), station.GetInputPort("actuation"))
    return builder.Build(), nmpc


def test_the_stations_first_command_follows_the_first_state_not_a_fallback():
    """The station waits for the first state at initialization and hands it out there, so the
    NMPC's update at t = 0 plans from it instead of braking a car it has not seen (a standing
    car braked that way reverses)."""
    scenario = memq_scenario()
    scenario.hardware.first_message_timeout_s = 1.0
    lcm, buses = shared_buses()
    diagram, nmpc = station_with_nmpc(scenario, buses)
    commands = []
    lcm.Subscribe(
        scenario.hardware.actuation_channel,
        lambda data: commands.append(lcmt_vehicle_actuation.decode(data)),
    )
    x = initial_state(scenario_course(scenario), load_vehicle(scenario.vehicle), 0.0)
    msg = lcmt_vehicle_state()
    msg.utime, msg.state, msg.valid = 0, list(map(float, x)), True
    lcm.Publish(scenario.hardware.state_channel, msg.encode())
    simulator = Simulator(diagram)
    simulator.Initialize()
    simulator.AdvanceTo(0.01)
    diag = nmpc.GetOutputPort("diagnostics").Eval(
        nmpc.GetMyContextFromRoot(simulator.get_context())
    )
    assert diag.mode == "qp" and diag.fallback_count == 0
    assert commands and commands[0].accel >= 0.0 and commands[0].state_utime == 0


def test_the_bridged_car_stands_until_the_first_command_then_drives():
    """``run_vehicle_bridge`` publishes the standing car's state, its time stamps rising, and
    integrates nothing until a command comes; then the car drives from its initial state."""
    scenario = memq_scenario()
    lcm = DrakeLcm("memq://")
    held = []

    def station(data):  # answers the third state message with its first command
        held.append(lcmt_vehicle_state.decode(data))
        if len(held) == 3:
            cmd = lcmt_vehicle_actuation()
            cmd.utime, cmd.state_utime = held[-1].utime, held[-1].utime
            cmd.steer_rate, cmd.accel = 0.0, 0.5
            lcm.Publish(scenario.hardware.actuation_channel, cmd.encode())

    lcm.Subscribe(scenario.hardware.state_channel, station)
    result = run_vehicle_bridge(scenario, duration_s=0.2, realtime_rate=1.0, lcm=lcm)
    first = held[:3]
    utimes = [m.utime for m in first]  # on the state ticks, rising: no duplicates
    assert utimes[0] == 0 and all(u % 10_000 == 0 for u in utimes)
    assert all(b > a for a, b in zip(utimes, utimes[1:], strict=False))
    assert all(m.state == first[0].state for m in first)  # the car stood still
    assert result.started_s > utimes[-1] * 1e-6 and result.stopped_because == "duration"
    assert first[0].state[3] == pytest.approx(3.0)  # held at the scenario's start speed
    truth = result.truth
    assert result.started_s <= truth["t"].iloc[0] < result.started_s + 0.05
    assert result.sim_time_s == pytest.approx(result.started_s + 0.2)  # 0.2 s of driving
    assert result.actuation_status["accepted"] == 1
    # Accelerating at the command's 0.5 m/s^2 from 3 m/s at the start: nothing moved before it,
    # and the watchdog never braked.
    driven = truth["t"].to_numpy() - result.started_s
    np.testing.assert_allclose(truth["v"], 3.0 + 0.5 * driven, atol=0.01)


def test_a_bridge_that_hears_no_command_stops_with_an_error_naming_the_field():
    scenario = memq_scenario()
    scenario.hardware.first_command_timeout_s = 0.1
    with pytest.raises(RuntimeError, match=r"PCVFE_ACTUATION at memq://.*first_command_timeout_s"):
        run_vehicle_bridge(scenario, duration_s=1.0, lcm=DrakeLcm("memq://"))


def test_the_bridge_warms_up_its_first_step_without_publishing():
    """``warm_up`` computes, on a throwaway context, the plant's derivatives and every
    publisher's message (the first step's one-off costs, paid before the car's clock starts)
    and sends nothing; the bridge's own context is left as it was."""
    from pydrake.systems.framework import BasicVector, LeafSystem
    from pydrake.systems.lcm import LcmPublisherSystem

    from pcvfe_drake.diagrams.warm_up import warm_up
    from pcvfe_drake.systems.vehicle_state_sender import VehicleStateSender

    calls = {"derivatives": 0, "state": 0}

    class Rolling(LeafSystem):  # one continuous state, its output the ST state the sender packs
        def __init__(self):
            super().__init__()
            self.DeclareContinuousState(1)
            self.DeclareVectorOutputPort("state", 7, self._out)

        def DoCalcTimeDerivatives(self, context, derivatives):
            calls["derivatives"] += 1
            derivatives.get_mutable_vector().SetAtIndex(0, 1.0)

        def _out(self, context, output: BasicVector):
            calls["state"] += 1
            output.SetFromVector(np.full(7, context.get_continuous_state_vector()[0]))

    lcm = DrakeLcm("memq://")
    heard = []
    lcm.Subscribe("WARM_STATE", heard.append)
    builder = DiagramBuilder()
    rolling = builder.AddSystem(Rolling())
    sender = builder.AddSystem(VehicleStateSender())
    publisher = builder.AddSystem(
        LcmPublisherSystem.Make(
            channel="WARM_STATE", lcm_type=lcmt_vehicle_state, lcm=lcm, publish_period=0.01
        )
    )
    builder.Connect(rolling.get_output_port(), sender.GetInputPort("state"))
    builder.Connect(sender.GetOutputPort("message"), publisher.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    assert warm_up(diagram) >= 0.0
    assert calls == {"derivatives": 1, "state": 1}
    lcm.HandleSubscriptions(0)
    assert heard == []  # nothing sent
    assert simulator.get_context().get_time() == 0.0
    simulator.AdvanceTo(0.015)  # the run itself publishes, from its own context
    lcm.HandleSubscriptions(0)
    assert len(heard) == 2


def test_the_bridge_warms_up_a_discrete_multi_body_plant():
    """The multi-body truth's default state is discrete: ``warm_up`` computes its first update
    (where the compiled integrator is loaded), on the throwaway context."""
    from pydrake.systems.primitives import ConstantVectorSource

    from pcvfe_drake.diagrams.warm_up import warm_up
    from pcvfe_drake.systems.vehicle_plant import VehiclePlant

    builder = DiagramBuilder()
    plant = builder.AddSystem(VehiclePlant(truth="mb", x0=[0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0]))
    source = builder.AddSystem(ConstantVectorSource(np.array([0.0, 1.0])))
    builder.Connect(source.get_output_port(), plant.get_actuation_input_port())
    diagram = builder.Build()
    advanced = []
    advance = plant.mb.advance
    plant.mb.advance = lambda *args: advanced.append(args[3]) or advance(*args)
    simulator = Simulator(diagram)
    context = plant.GetMyContextFromRoot(simulator.get_context())
    before = context.get_discrete_state(0).CopyToVector()
    assert diagram.EvalTimeDerivatives(simulator.get_context()).size() == 0
    warm_up(diagram)
    assert advanced == [plant.mb_period_s]
    np.testing.assert_array_equal(context.get_discrete_state(0).CopyToVector(), before)
