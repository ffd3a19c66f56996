"""FrictionCircleView: circles of mu_hat g and true mu g, planned and actual accelerations at
the right panel coordinates; utilisation > 1 turns red; no truth circle without truth."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from pcvfe_drake.control.plan import NmpcPlan
from pcvfe_drake.systems.friction_circle_view import FrictionCircleView
from pcvfe_drake.views.plan_geometry import G_MPS2

N = 4


@pytest.fixture
def meshcat(local_meshcat_server):
    return local_meshcat_server


def publish(view, values: dict, t_end: float = 0.15):
    simulator = Simulator(view)
    context = simulator.get_mutable_context()
    for name, value in values.items():
        view.GetInputPort(name).FixValue(context, value)
    simulator.AdvanceTo(t_end)
    return simulator


def make_plan() -> NmpcPlan:
    x = np.zeros((N + 1, 7))
    x[:, 3] = 10.0  # v [m/s]
    x[:, 5] = [0.1, 0.2, 0.3, 0.9, 0.9]  # psi_dot [rad/s]: a_y = 1, 2, 3, 9 m/s^2
    u = np.zeros((N, 2))
    u[:, 1] = [1.0, 0.0, -1.0, 0.0]  # accel [m/s^2]
    return NmpcPlan(x, u, np.zeros((N, 2)), np.zeros(N), "qp", "", 0.5, 0.0)


def test_circles_points_and_utilisation(meshcat, probe):
    scale = 0.5
    view = FrictionCircleView(
        meshcat, has_truth=True, horizon=N, stride=1, m_per_mps2=scale, offset_m=(0, 0, 9)
    )
    state = np.array([10.0, 20.0, 0.0, 10.0, 0.0, 0.5, 0.0])  # a_y = 5 m/s^2
    values = {
        "state": state,
        "actuation": np.array([0.0, 3.0]),  # a_x = 3: |a| = 5.83 > 0.5 g = 4.9
        "theta_hat": np.array([0.8, 20.0, 20.0]),
        "plan": make_plan(),
        "true_mu": np.array([0.5]),
    }
    publish(view, values)
    np.testing.assert_allclose(probe.translation(meshcat, "/pcvfe/friction_circle"), [10, 20, 9])
    assert meshcat.HasPath("/pcvfe/friction_circle/mu_hat/line")
    assert meshcat.HasPath("/pcvfe/friction_circle/mu_true/line")
    r_hat = probe.scale(meshcat, "/pcvfe/friction_circle/mu_hat")
    np.testing.assert_allclose(r_hat, [0.8 * G_MPS2 * scale, 1.0, 0.8 * G_MPS2 * scale])
    r_true = probe.scale(meshcat, "/pcvfe/friction_circle/mu_true")
    np.testing.assert_allclose(r_true, [0.5 * G_MPS2 * scale, 1.0, 0.5 * G_MPS2 * scale])
    # Planned points: (a_x, a_y) -> panel (-a_y, a_x) * scale.
    for k, (ax, ay) in enumerate([(1, 1), (0, 2), (-1, 3), (0, 9)]):
        p = probe.translation(meshcat, f"/pcvfe/friction_circle/planned/{k:02d}")
        np.testing.assert_allclose(p, [-ay * scale, -0.1, ax * scale], atol=1e-9)
    # 9 m/s^2 is beyond 0.8 g = 7.85: only the last planned point is "over" (red).
    assert [c.shown for c in view._planned] == [False, False, False, True]
    p = probe.translation(meshcat, "/pcvfe/friction_circle/actual")
    np.testing.assert_allclose(p, [-5 * scale, -0.1, 3 * scale])
    assert view._actual.shown is True  # against the true mu 0.5
    red = view._actual.path(True)
    assert probe.visible(meshcat, red) is True and b"SphereGeometry" in probe.object_bytes(
        meshcat, red
    )
    util = np.hypot(3, 5) / (0.5 * G_MPS2)
    assert view._label.shown == f"utilisation {util:.1f}"


def test_without_truth_there_is_no_true_circle(meshcat):
    view = FrictionCircleView(meshcat, has_truth=False, horizon=N)
    assert not view.HasInputPort("true_mu")
    values = {
        "state": np.array([0.0, 0.0, 0.0, 10.0, 0.0, 0.5, 0.0]),
        "actuation": np.array([0.0, 3.0]),
        "theta_hat": np.array([0.8, 20.0, 20.0]),
        "plan": NmpcPlan(),
    }
    publish(view, values)
    assert meshcat.HasPath("/pcvfe/friction_circle/mu_hat/line")
    assert not meshcat.HasPath("/pcvfe/friction_circle/mu_true")
    assert view._actual.shown is False  # 5.83 < 0.8 g: inside the believed circle
    assert all(c.shown is None for c in view._planned)  # no plan, no planned points
