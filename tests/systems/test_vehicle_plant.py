"""Tests of the VehiclePlant LeafSystem (ST and MB truth, terrain friction, bad input)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource
from vehiclemodels.parameters_vehicle1 import parameters_vehicle1
from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb

from pcvfe_drake.diagrams.world_io import world_terrain_map
from pcvfe_drake.systems.vehicle_plant import VehiclePlant
from pcvfe_drake.vehicle.mb_truth import MbSingularity, MbTruth, st_state
from pcvfe_drake.vehicle.params import ford_escort, roboracer
from pcvfe_drake.vehicle.single_track import rollout, st_dynamics

# A point well inside each quadrant of the default map, with its terrain's mu.
SPOTS = {"patchy_grass": (30.0, 30.0), "brick": (-30.0, 30.0), "sand": (-30.0, -30.0)}


@pytest.fixture(scope="module")
def terrain_map():
    return world_terrain_map("paper")


def test_ports_and_no_direct_feedthrough(terrain_map):
    plant = VehiclePlant(terrain_map=terrain_map, x0=[30.0, 30.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    assert plant.get_input_port(0).get_name() == "actuation"
    assert [plant.get_output_port(i).get_name() for i in range(3)] == [
        "state",
        "true_mu",
        "true_terrain",
    ]
    assert plant.get_actuation_input_port().size() == 2
    assert plant.get_state_output_port().size() == 7
    for i in range(3):
        assert not plant.HasDirectFeedthrough(0, i)


@pytest.mark.parametrize("terrain", sorted(SPOTS))
def test_st_derivatives_use_the_mu_under_the_car(terrain_map, terrain):
    params = ford_escort()
    sx, sy = SPOTS[terrain]
    x = np.array([sx, sy, 0.08, 12.0, 0.4, 0.3, 0.02])
    u = np.array([0.1, 1.5])
    plant = VehiclePlant(params, terrain_map, truth="st", x0=x)
    context = plant.CreateDefaultContext()
    plant.get_actuation_input_port().FixValue(context, u)
    xdot = plant.EvalTimeDerivatives(context).CopyToVector()
    mu = terrain_map.terrain(terrain).mu
    expected = st_dynamics(x, u, params, theta=[mu, params.C_Sf, params.C_Sr])
    np.testing.assert_allclose(xdot, expected, rtol=1e-12, atol=1e-12)
    nominal = st_dynamics(x, u, params)  # params.mu = 1.0489: a plant ignoring the map fails
    assert abs(xdot[5] - nominal[5]) > 0.05
    np.testing.assert_array_equal(plant.get_state_output_port().Eval(context), x)
    assert plant.get_true_mu_output_port().Eval(context)[0] == mu
    index = plant.get_true_terrain_output_port().Eval(context)[0]
    assert terrain_map.terrains[int(index)].name == terrain


def test_without_map_uses_params_mu():
    params = ford_escort().replace(mu=0.7)
    x = np.array([0.0, 0.0, 0.05, 8.0, 0.0, 0.1, 0.0])
    plant = VehiclePlant(params, x0=x)
    context = plant.CreateDefaultContext()
    plant.get_actuation_input_port().FixValue(context, [0.0, 0.0])
    np.testing.assert_allclose(
        plant.EvalTimeDerivatives(context).CopyToVector(), st_dynamics(x, [0.0, 0.0], params)
    )
    assert plant.get_true_mu_output_port().Eval(context)[0] == 0.7
    assert plant.get_true_terrain_output_port().Eval(context)[0] == -1.0


def test_mb_derivatives_match_the_package(terrain_map):
    x_st = np.array([-30.0, -30.0, 0.05, 10.0, 1.0, 0.2, 0.01])  # sand, mu 0.45
    plant = VehiclePlant(
        ford_escort(), terrain_map, truth="mb", x0=x_st, mb_integration="continuous"
    )
    context = plant.CreateDefaultContext()
    u = np.array([-0.2, 0.8])
    plant.get_actuation_input_port().FixValue(context, u)
    x = context.get_continuous_state_vector().CopyToVector()
    assert x.size == 29
    p = copy.deepcopy(parameters_vehicle1())
    scale = 0.45 / p.tire.p_dy1
    for name in ("p_dy1", "p_dx1", "p_ky1", "p_kx1"):
        setattr(p.tire, name, getattr(p.tire, name) * scale)
    expected = vehicle_dynamics_mb(x.tolist(), u.tolist(), p)
    np.testing.assert_allclose(
        plant.EvalTimeDerivatives(context).CopyToVector(), expected, rtol=1e-12, atol=1e-12
    )
    np.testing.assert_allclose(plant.get_state_output_port().Eval(context), x_st, atol=1e-12)
    assert plant.get_true_mu_output_port().Eval(context)[0] == 0.45


def test_mb_discrete_update_is_one_rk4_period(terrain_map):
    x_st = np.array([30.0, -30.0, 0.0, 10.0, 0.0, 0.0, 0.0])  # concrete, mu 0.6
    plant = VehiclePlant(ford_escort(), terrain_map, truth="mb", x0=x_st, mb_method="rk4")
    context = plant.CreateDefaultContext()
    u = np.array([0.2, 1.0])
    plant.get_actuation_input_port().FixValue(context, u)
    updated = plant.EvalUniquePeriodicDiscreteUpdate(context).get_vector(0).CopyToVector()
    mb = MbTruth()
    expected = mb.integrate(mb.initial_state(x_st), u, 0.6, 0.01, method="rk4")
    np.testing.assert_allclose(updated, expected, rtol=1e-12, atol=1e-12)


def test_the_default_mb_update_integrates_a_period_to_the_fine_reference(terrain_map):
    """The default MB realisation: a discrete update every 10 ms by compiled error-controlled
    steps, the step carried in the context from one update to the next. Over 2 s of driving
    (accelerating through a steering ramp) it lands within a millimetre of 0.1 ms RK4
    substeps, with the same mu per period."""
    x_st = np.array([30.0, -30.0, 0.0, 8.0, 0.0, 0.0, 0.0])  # concrete, mu 0.6
    plant = VehiclePlant(ford_escort(), terrain_map, truth="mb", x0=x_st)
    assert (plant.mb_integration, plant.mb_method) == ("discrete", "rk23")
    context = plant.CreateDefaultContext()
    assert context.num_continuous_states() == 0
    u = np.array([0.1, 1.0])
    plant.get_actuation_input_port().FixValue(context, u)
    mb = MbTruth()
    reference = mb.initial_state(x_st)
    steps = []
    for k in range(200):
        context.SetTime(0.01 * k)
        update = plant.EvalUniquePeriodicDiscreteUpdate(context)
        steps.append(update.get_vector(1).GetAtIndex(0))
        context.SetDiscreteState(0, update.get_vector(0).CopyToVector())
        context.SetDiscreteState(1, update.get_vector(1).CopyToVector())
        reference = mb.integrate(reference, u, 0.6, 0.01, method="rk4", rk4_step_s=1e-4)
    x = context.get_discrete_state(0).CopyToVector()
    assert np.hypot(*(x[:2] - reference[:2])) < 1e-3
    assert abs(x[3] - reference[3]) < 1e-4
    # the step is carried, set by error control, not the period
    assert len(set(steps)) > 10 and min(steps) < 0.005
    plant.set_initial_state(context, x_st)
    assert context.get_discrete_state(1).GetAtIndex(0) == 0.01


def test_every_command_drives_the_discrete_mb_from_the_instant_it_is_computed(terrain_map):
    """A controller's unrestricted update every 0.05 s and the plant's discrete update every
    0.01 s: Drake computes each event's times from its own period, and they differ in the last
    bits at some multiples (0.15 s, 0.3 s, ...). The plant updates 1 us after the grid, so every
    command is integrated from its instant: 1 s of alternating commands lands exactly on the
    same steps taken with each command from its update."""

    class Command(LeafSystem):
        def __init__(self):
            super().__init__()
            self.index = self.DeclareDiscreteState(2)
            self.DeclarePeriodicUnrestrictedUpdateEvent(0.05, 0.0, self._update)
            self.DeclareStateOutputPort("u", self.index)

        def _update(self, context, state):
            k = round(context.get_time() / 0.05)
            state.get_mutable_discrete_state(self.index).SetFromVector([0.0, 2.0 * (k % 2)])

    x_st = np.array([30.0, -30.0, 0.0, 8.0, 0.0, 0.0, 0.0])
    builder = DiagramBuilder()
    plant = builder.AddSystem(VehiclePlant(ford_escort(), terrain_map, truth="mb", x0=x_st))
    command = builder.AddSystem(Command())
    builder.Connect(command.get_output_port(), plant.get_actuation_input_port())
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(1.0)
    x = plant.GetMyContextFromRoot(simulator.get_context()).get_discrete_state(0).CopyToVector()
    mb = MbTruth()
    pv = mb.parameter_vector_for_mu(0.6)
    expected, step = mb.initial_state(x_st), 0.01
    for j in range(100):  # updates at j * 0.01 + 1 us, each with the command of update j // 5
        expected, step = mb.advance(expected, [0.0, 2.0 * ((j // 5) % 2)], pv, 0.01, step)
    np.testing.assert_array_equal(x, expected)


def simulate(plant, u, duration_s: float):
    builder = DiagramBuilder()
    builder.AddSystem(plant)
    source = builder.AddSystem(ConstantVectorSource(np.asarray(u, dtype=float)))
    builder.Connect(source.get_output_port(), plant.get_actuation_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(duration_s)
    return plant.GetMyContextFromRoot(simulator.get_context())


def test_st_simulation_matches_rollout_and_crosses_terrain(terrain_map):
    params = ford_escort()
    x0 = np.array([-20.0, 30.0, 0.0, 10.0, 0.0, 0.0, 0.0])  # brick, heading east to grass
    u = [0.02, 0.5]
    plant = VehiclePlant(params, terrain_map, x0=x0)
    start = plant.CreateDefaultContext()
    assert terrain_map.terrains[int(plant.get_true_terrain_output_port().Eval(start)[0])].name == (
        "brick"
    )
    context = simulate(plant, u, 3.5)
    x = plant.get_state_output_port().Eval(context)
    assert x[0] > 15.0
    assert plant.get_true_mu_output_port().Eval(context)[0] == pytest.approx(0.3)
    assert terrain_map.name_at(x[:2]) == "patchy_grass"
    # Straight-ish driving at constant mu on each side: compare with the core rollout on brick
    # for the first second (still on brick).
    early_plant = VehiclePlant(params, terrain_map, x0=x0)
    early = simulate(early_plant, u, 1.0)
    ref = rollout(x0, np.tile(u, (100, 1)), params, 0.01, theta=[0.8, params.C_Sf, params.C_Sr])
    np.testing.assert_allclose(early_plant.get_state_output_port().Eval(early), ref[-1], atol=1e-3)


def test_mb_simulation_matches_the_core_integrator(terrain_map):
    x0 = np.array([30.0, -30.0, 0.05, 10.0, 0.0, 0.0, 0.0])
    u = np.array([0.0, 0.5])
    plant = VehiclePlant(ford_escort(), terrain_map, truth="mb", x0=x0)
    context = simulate(plant, u, 0.5)
    mb = MbTruth()
    ref = mb.integrate(mb.initial_state(x0), u, 0.6, 0.5, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(
        plant.get_state_output_port().Eval(context), st_state(ref), atol=2e-3
    )


def test_bad_input_gives_a_clear_error(terrain_map):
    plant = VehiclePlant(terrain_map=terrain_map, x0=[30.0, 30.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    context = plant.CreateDefaultContext()
    plant.get_actuation_input_port().FixValue(context, [np.nan, 0.0])
    with pytest.raises(ValueError, match=r"input 'actuation'.*\[nan, 0.0\].*not finite"):
        plant.EvalTimeDerivatives(context)
    with pytest.raises(ValueError, match="input 'actuation'"):
        simulate(
            VehiclePlant(terrain_map=terrain_map, x0=[30.0, 30.0, 0.0, 5.0, 0.0, 0.0, 0.0]),
            [0.0, np.inf],
            0.1,
        )
    mb_plant = VehiclePlant(truth="mb", x0=[0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    mb_context = mb_plant.CreateDefaultContext()
    mb_plant.get_actuation_input_port().FixValue(mb_context, [0.0, np.nan])
    with pytest.raises(ValueError, match="input 'actuation'"):
        mb_plant.EvalUniquePeriodicDiscreteUpdate(mb_context)
    with pytest.raises(ValueError, match="outside the terrain map"):
        VehiclePlant(terrain_map=terrain_map, x0=[500.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="x0 must be 7 finite numbers"):
        VehiclePlant(x0=[0.0, 0.0, np.nan, 5.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="truth='bicycle'"):
        VehiclePlant(truth="bicycle")
    with pytest.raises(ValueError, match="no CommonRoad multi-body parameters"):
        VehiclePlant(roboracer(), truth="mb")


def test_set_initial_state(terrain_map):
    plant = VehiclePlant(terrain_map=terrain_map, truth="mb")
    context = plant.CreateDefaultContext()
    x_st = np.array([-30.0, 30.0, 0.0, 7.0, 0.5, 0.0, 0.0])
    plant.set_initial_state(context, x_st)
    np.testing.assert_allclose(plant.get_state_output_port().Eval(context), x_st, atol=1e-12)
    assert plant.get_true_mu_output_port().Eval(context)[0] == 0.8


@pytest.mark.parametrize("integration", ["continuous", "discrete"])
def test_the_mb_truth_reversing_raises_its_singularity_with_the_time(integration):
    """A car reversing at -0.5 m/s is outside the multi-body model (a wheel's ground speed
    <= 0): the plant says so with the simulated time, for the run loop to score."""
    plant = VehiclePlant(
        truth="mb", x0=[1.0, 2.0, 0.0, -0.5, 0.0, 0.0, 0.0], mb_integration=integration
    )
    ctx = plant.CreateDefaultContext()
    ctx.SetTime(3.25)
    plant.get_actuation_input_port().FixValue(ctx, [0.0, 0.0])
    with pytest.raises(MbSingularity, match="reversing") as caught:
        if integration == "continuous":
            plant.EvalTimeDerivatives(ctx)
        else:
            Simulator(plant, ctx).AdvanceTo(3.3)
    assert caught.value.t_s == pytest.approx(3.25)  # a discrete update at its start
    assert "t = 3.2" in str(caught.value)
    np.testing.assert_allclose(caught.value.state[:2], [1.0, 2.0])
