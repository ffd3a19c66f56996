"""Nmpc LeafSystem: ports, held output, no feedthrough, fixed theta, diagnostics."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from pcvfe_drake.control.course import initial_state
from pcvfe_drake.control.nmpc import NmpcConfig, NmpcDiagnostics, NmpcMemory
from pcvfe_drake.systems.nmpc import Nmpc


@pytest.fixture(scope="module")
def nmpc():
    return Nmpc("slalom", config=NmpcConfig(horizon=20))


def test_ports_and_no_direct_feedthrough(nmpc):
    assert nmpc.GetInputPort("state").size() == 7
    assert nmpc.GetInputPort("theta_hat").size() == 3
    assert nmpc.GetOutputPort("actuation").size() == 2
    for i in range(nmpc.num_input_ports()):
        for o in range(nmpc.num_output_ports()):
            assert not nmpc.HasDirectFeedthrough(i, o)
    # The period is the controller's step (20 Hz by default).
    assert nmpc.period_s == pytest.approx(0.05)


def test_output_held_between_updates_and_diagnostics(nmpc):
    ctx = nmpc.CreateDefaultContext()
    x0 = initial_state(nmpc.controller.course, nmpc.params, 5.0, 30.0)
    x0[0] += 0.5  # off the path, so the controller has work to do
    nmpc.GetInputPort("state").FixValue(ctx, x0)
    nmpc.GetInputPort("theta_hat").FixValue(ctx, [0.45, nmpc.params.C_Sf, nmpc.params.C_Sr])
    out = nmpc.GetOutputPort("actuation")
    np.testing.assert_array_equal(out.Eval(ctx), [0.0, 0.0])  # before the first update
    sim = Simulator(nmpc, ctx)
    sim.AdvanceTo(0.01)
    u1 = out.Eval(ctx).copy()
    assert np.any(u1 != 0.0)
    # Same as the core controller's first step from the same state and belief.
    u_ref, _, _ = nmpc.controller.step(x0, [0.45, nmpc.params.C_Sf, nmpc.params.C_Sr], NmpcMemory())
    np.testing.assert_allclose(u1, u_ref, atol=1e-3)
    sim.AdvanceTo(0.049)
    np.testing.assert_array_equal(out.Eval(ctx), u1)  # held: no re-solve on evaluation
    diag = nmpc.GetOutputPort("diagnostics").Eval(ctx)
    assert isinstance(diag, NmpcDiagnostics)
    assert diag.updates == 1 and diag.mode == "qp" and diag.mu_hat == pytest.approx(0.45)
    sim.AdvanceTo(0.051)
    assert nmpc.GetOutputPort("diagnostics").Eval(ctx).updates == 2


def test_fixed_theta_ignores_the_unconnected_input():
    sys_ = Nmpc(
        "slalom",
        config=NmpcConfig(horizon=20),
        fixed_theta=[0.3, 20.898, 20.898],
    )
    ctx = sys_.CreateDefaultContext()
    sys_.GetInputPort("state").FixValue(
        ctx, initial_state(sys_.controller.course, sys_.params, 5.0, 0.0)
    )
    Simulator(sys_, ctx).AdvanceTo(0.0)
    diag = sys_.GetOutputPort("diagnostics").Eval(ctx)
    assert diag.mode == "qp" and diag.mu_hat == pytest.approx(0.3)
    with pytest.raises(ValueError, match="fixed_theta"):
        Nmpc("slalom", fixed_theta=[np.nan, 1.0, 1.0])


def test_closed_loop_with_the_vehicle_plant_tracks():
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from pcvfe_drake.systems.vehicle_plant import VehiclePlant

    ctrl = Nmpc("slalom", config=NmpcConfig())
    course, params = ctrl.controller.course, ctrl.params
    x0 = initial_state(course, params, 5.0, 100.0)
    x0[1] += 0.5  # start half a metre off the path
    builder = DiagramBuilder()
    plant = builder.AddNamedSystem("plant", VehiclePlant(params, x0=x0))
    nmpc = builder.AddNamedSystem("nmpc", ctrl)
    theta = builder.AddNamedSystem("theta", ConstantVectorSource(params.theta))
    builder.Connect(plant.GetOutputPort("state"), nmpc.GetInputPort("state"))
    builder.Connect(theta.get_output_port(), nmpc.GetInputPort("theta_hat"))
    builder.Connect(nmpc.GetOutputPort("actuation"), plant.GetInputPort("actuation"))
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(3.0)
    ctx = diagram.GetSubsystemContext(plant, sim.get_context())
    x = plant.GetOutputPort("state").Eval(ctx)
    p = course.project(x[:2])
    assert abs(float(p.lateral_error)) < 0.1
    assert x[3] == pytest.approx(course.speed, abs=0.3)
    diag = nmpc.GetOutputPort("diagnostics").Eval(
        diagram.GetSubsystemContext(nmpc, sim.get_context())
    )
    assert diag.updates == 60 and diag.fallback_count == 0
