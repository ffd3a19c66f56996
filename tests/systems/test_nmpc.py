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


def test_plan_output_is_the_solved_plan_with_its_reference_window(nmpc):
    ctx = nmpc.CreateDefaultContext()
    course = nmpc.controller.course
    x0 = initial_state(course, nmpc.params, 5.0, 30.0)
    nmpc.GetInputPort("state").FixValue(ctx, x0)
    nmpc.GetInputPort("theta_hat").FixValue(ctx, [0.45, nmpc.params.C_Sf, nmpc.params.C_Sr])
    plan = nmpc.GetOutputPort("plan").Eval(ctx)
    assert plan.mode == "none" and not plan.has_prediction  # before the first update
    sim = Simulator(nmpc, ctx)
    sim.AdvanceTo(0.06)  # updates at 0 and 0.05
    plan = nmpc.GetOutputPort("plan").Eval(ctx)
    n = nmpc.controller.N
    assert plan.mode == "qp" and plan.reason == "" and plan.time_s == pytest.approx(0.05)
    assert plan.x_pred.shape == (n + 1, 7) and plan.u_pred.shape == (n, 2)
    assert plan.mu_hat == pytest.approx(0.45)
    # The first planned input is what was applied; the plan starts at the measured state.
    np.testing.assert_allclose(plan.u_pred[0], nmpc.GetOutputPort("actuation").Eval(ctx))
    np.testing.assert_allclose(plan.x_pred[0], x0, atol=1e-4)  # dx_0 = 0 to OSQP tolerance
    # The reference window lies on the course, ahead of the car, near the predicted positions.
    proj = course.project(plan.ref_xy)
    np.testing.assert_allclose(proj.lateral_error, 0.0, atol=1e-6)
    assert np.all(np.diff(proj.s) > 0) and proj.s[0] > course.project(x0[:2]).s
    assert np.max(np.hypot(*(plan.ref_xy - plan.x_pred[1:, :2]).T)) < 0.5
    assert plan.v_ref_mps.shape == (n,) and np.all(plan.v_ref_mps > 0)


def test_plan_of_a_fallback_carries_the_reason():
    sys_ = Nmpc("slalom", config=NmpcConfig(horizon=20))
    ctx = sys_.CreateDefaultContext()
    sys_.GetInputPort("state").FixValue(ctx, np.full(7, np.nan))
    sys_.GetInputPort("theta_hat").FixValue(ctx, [0.45, sys_.params.C_Sf, sys_.params.C_Sr])
    Simulator(sys_, ctx).AdvanceTo(0.01)
    plan = sys_.GetOutputPort("plan").Eval(ctx)
    assert plan.mode == "braking" and plan.reason == "state not finite"
    assert plan.is_fallback and not plan.has_prediction


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
