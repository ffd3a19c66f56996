"""PlanView: the predicted trajectory, reference window and fallback marker land where they
should, coloured by speed, and follow the plan over time in a recording."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from pcvfe_drake.control.plan import NmpcPlan
from pcvfe_drake.systems.plan_view import PlanView
from pcvfe_drake.views.plan_geometry import speed_bins

N = 8


@pytest.fixture
def meshcat(local_meshcat_server):
    return local_meshcat_server


def straight_plan(t: float, mode: str = "qp", reason: str = "") -> NmpcPlan:
    x = np.zeros((N + 1, 7))
    x[:, 0] = np.arange(N + 1) * 2.0 + t  # sx [m]
    x[:, 1] = 1.0
    x[:, 3] = np.linspace(1.0, 14.0, N + 1)  # v [m/s], slow to fast
    u = np.zeros((N, 2))
    ref = np.column_stack([x[1:, 0], np.zeros(N)])
    return NmpcPlan(x, u, ref, x[1:, 3], mode, reason, 0.5, t)


def run(view, plan_at, state, t_end):
    simulator = Simulator(view)
    context = simulator.get_mutable_context()
    view.GetInputPort("state").FixValue(context, state)
    port = view.GetInputPort("plan")
    port.FixValue(context, plan_at(0.0))
    simulator.Initialize()
    t = 0.0
    while t < t_end - 1e-9:
        t = min(t + 0.1, t_end)
        port.FixValue(context, plan_at(t))
        simulator.AdvanceTo(t)
    return simulator


def test_trajectory_reference_and_colours(meshcat, probe):
    view = PlanView(meshcat, horizon=N, v_max_mps=15.0, stride=2, reference_stride=3)
    np.testing.assert_array_equal(view.stages, [0, 2, 4, 6, 8])
    state = np.array([0.0, 1.0, 0, 5.0, 0, 0, 0])
    run(view, lambda t: straight_plan(1.0), state, 0.2)
    plan = straight_plan(1.0)
    bins = speed_bins(plan.x_pred[:, 3], 15.0)
    assert bins[0] == 0 and bins[-1] == 4  # the scale spans blue .. red
    for i, k in enumerate(view.stages):
        parent = f"/pcvfe/plan/trajectory/{i:02d}"
        np.testing.assert_allclose(
            probe.translation(meshcat, parent), [plan.x_pred[k, 0], 1.0, 0.4]
        )
        assert meshcat.HasPath(f"{parent}/00000")
        assert b"SphereGeometry" in probe.object_bytes(meshcat, f"{parent}/00000")
    # The reference window: stages 0, 3, 6, 7 of the N reference points.
    for i, k in enumerate([0, 3, 6, 7]):
        np.testing.assert_allclose(
            probe.translation(meshcat, f"/pcvfe/plan/reference/{i:02d}"),
            [plan.ref_xy[k, 0], 0, 0.2],
        )
    assert not meshcat.HasPath("/pcvfe/plan/fallback/marker/00000")


def test_fallback_marker_with_reason_and_recording(meshcat, probe):
    view = PlanView(meshcat, horizon=N, v_max_mps=15.0)
    state = np.array([3.0, -2.0, 0, 5.0, 0, 0, 0])

    def plan_at(t):
        if t < 0.25:
            return straight_plan(t)
        return NmpcPlan(mode="braking", reason="osqp: maximum iterations reached", time_s=t)

    meshcat.StartRecording(frames_per_second=10.0)
    run(view, plan_at, state, 0.5)
    meshcat.StopRecording()
    assert meshcat.HasPath("/pcvfe/plan/fallback/marker/00000")
    np.testing.assert_allclose(probe.translation(meshcat, "/pcvfe/plan/fallback"), [3.0, -2.0, 0.0])
    reason = view._reason.shown
    assert reason == "braking: osqp: maximum iterations reached"
    # A braking update without a plan hides the trajectory points it had before.
    assert all(choice.shown is None for choice in view._points)
    meshcat.DeleteRecording()


def test_bad_arguments(meshcat):
    with pytest.raises(ValueError, match="v_max_mps"):
        PlanView(meshcat, horizon=N, v_max_mps=0.0)
    with pytest.raises(ValueError, match="horizon"):
        PlanView(meshcat, horizon=0, v_max_mps=10.0)
