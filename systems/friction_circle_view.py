"""FrictionCircleView: the tyres' limit in Meshcat, under ``/pcvfe/friction_circle``."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Meshcat, Rgba, Sphere
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from pcvfe_drake.control.plan import NmpcPlan
from pcvfe_drake.systems.meshcat_layer import ROOT, TextLabel, VisibleChoice, follow_car
from pcvfe_drake.vehicle.single_track import NU, NX
from pcvfe_drake.views.plan_geometry import (
    G_MPS2,
    actual_acceleration,
    planned_accelerations,
    stride_indices,
    unit_circle,
    utilisation,
)

PATH = f"{ROOT}/friction_circle"
OK_RGB = (0.2, 0.85, 0.3)
OVER_RGB = (1.0, 0.1, 0.1)


class FrictionCircleView(LeafSystem):
    """A g-g diagram floating above the car: accelerations against the friction circles.

    A vertical panel (facing south, -y, like the default camera) that follows the car's position
    at ``offset_m``; lateral acceleration a_y [m/s^2] to the left, longitudinal a_x up, at
    ``m_per_mps2`` metres per m/s^2:

    - ``/pcvfe/friction_circle/mu_hat``: orange circle of radius ``mu_hat * g``;
    - ``/pcvfe/friction_circle/mu_true``: blue circle of the true ``mu * g``, only when built
      with ``has_truth=True`` (a station with a ``true_mu`` port);
    - ``/pcvfe/friction_circle/planned/<i>``: the planned ``(a_x, a_y)`` over the horizon (every
      ``stride``-th stage), green inside the mu_hat circle, red beyond it;
    - ``/pcvfe/friction_circle/actual``: the applied ``a_x`` and measured ``a_y = v psi_dot``,
      a white sphere, a bigger red one when its utilisation (against the true mu where there is
      truth, else mu_hat) exceeds 1; ``/pcvfe/friction_circle/utilisation`` says it as text
      (rounded to 0.1).

    .. pydrake_system::

        name: FrictionCircleView
        input_ports:
        - state
        - actuation
        - theta_hat
        - plan
        - true_mu (only with has_truth)

    Rate: one periodic publish every ``period_s`` (default 0.1 s).
    """

    def __init__(
        self,
        meshcat: Meshcat,
        *,
        has_truth: bool,
        horizon: int,
        period_s: float = 0.1,
        stride: int = 4,
        m_per_mps2: float = 0.5,
        offset_m=(-7.0, 0.0, 9.0),
        mu_max: float = 1.2,
    ) -> None:
        super().__init__()
        if not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"FrictionCircleView: period_s must be > 0, got {period_s!r}")
        if not (np.isfinite(m_per_mps2) and m_per_mps2 > 0):
            raise ValueError(f"FrictionCircleView: m_per_mps2 must be > 0, got {m_per_mps2!r}")
        self._meshcat = meshcat
        self._has_truth = bool(has_truth)
        self._scale = float(m_per_mps2)
        self._offset = np.asarray(offset_m, dtype=float).reshape(3)
        self._mu_max = float(mu_max)
        self._stages = stride_indices(int(horizon), stride)
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._actuation_port = self.DeclareVectorInputPort("actuation", NU)
        self._theta_port = self.DeclareVectorInputPort("theta_hat", 3)
        self._plan_port = self.DeclareAbstractInputPort("plan", AbstractValue.Make(NmpcPlan()))
        self._true_mu_port = self.DeclareVectorInputPort("true_mu", 1) if self._has_truth else None
        self.DeclareInitializationPublishEvent(self._draw_static)
        self.DeclarePeriodicPublishEvent(period_sec=period_s, offset_sec=0.0, publish=self._draw)
        self._planned: list[VisibleChoice] = []
        self._actual: VisibleChoice | None = None
        self._label: TextLabel | None = None

    def panel_point(self, a_xy: np.ndarray) -> np.ndarray:
        """Panel coordinates [m] (N, 3) of accelerations (N, 2) ``(a_x, a_y)`` [m/s^2]."""
        a = np.asarray(a_xy, dtype=float).reshape(-1, 2)
        return np.column_stack([-a[:, 1], np.full(len(a), -0.1), a[:, 0]]) * [
            self._scale,
            1.0,
            self._scale,
        ]

    def _draw_static(self, context) -> None:
        mc = self._meshcat
        mc.Delete(PATH)
        r_max = 1.05 * self._mu_max * G_MPS2 * self._scale
        mc.SetObject(f"{PATH}/panel", Box(2 * r_max, 0.05, 2 * r_max), Rgba(0.05, 0.05, 0.1, 0.55))
        mc.SetLineSegments(
            f"{PATH}/axes",
            np.array([[-r_max, 0.0, 0.0], [0.0, -0.08, -r_max]]).T,
            np.array([[r_max, 0.0, 0.0], [0.0, -0.08, r_max]]).T,
            1.0,
            Rgba(0.8, 0.8, 0.8, 1.0),
        )
        mc.SetTransform(f"{PATH}/axes", RigidTransform([0.0, -0.08, 0.0]))
        circle = unit_circle(96)
        line = np.asfortranarray(np.vstack([circle[:, 0], np.zeros(len(circle)), circle[:, 1]]))
        mc.SetLine(f"{PATH}/mu_hat/line", line, 3.0, Rgba(1.0, 0.5, 0.05, 1.0))
        if self._has_truth:
            mc.SetLine(f"{PATH}/mu_true/line", line, 3.0, Rgba(0.2, 0.55, 1.0, 1.0))
        self._planned = [
            VisibleChoice(mc, f"{PATH}/planned/{i:02d}") for i in range(len(self._stages))
        ]
        self._actual = VisibleChoice(mc, f"{PATH}/actual")
        self._label = TextLabel(mc, f"{PATH}/utilisation", height_m=0.9, max_texts=40)
        mc.SetTransform(f"{PATH}/utilisation", RigidTransform([-r_max, -0.1, r_max + 0.8]))

    def _sphere(self, radius: float, rgb):
        def create(path: str) -> None:
            self._meshcat.SetObject(path, Sphere(radius), Rgba(*rgb, 1.0))

        return create

    def _set_circle(self, name: str, mu: float, t: float) -> None:
        r = mu * G_MPS2 * self._scale if np.isfinite(mu) and mu > 0 else 1e-3
        self._meshcat.SetProperty(f"{PATH}/{name}", "scale", [r, 1.0, r], t)

    def _draw(self, context) -> None:
        t = context.get_time()
        mc = self._meshcat
        x = self._state_port.Eval(context)
        if not follow_car(mc, PATH, x, self._offset, t):
            return
        mu_hat = float(self._theta_port.Eval(context)[0])
        self._set_circle("mu_hat", mu_hat, t)
        mu_limit = mu_hat
        if self._has_truth:
            mu_true = float(self._true_mu_port.Eval(context)[0])
            self._set_circle("mu_true", mu_true, t)
            mu_limit = mu_true
        plan: NmpcPlan = self._plan_port.Eval(context)
        a_plan = np.zeros((0, 2))
        if plan.has_prediction:
            a_plan = planned_accelerations(plan.x_pred, plan.u_pred)
        util_plan = utilisation(a_plan, mu_hat)
        for choice, k in zip(self._planned, self._stages, strict=True):
            if k < len(a_plan) and np.all(np.isfinite(a_plan[k])):
                p = self.panel_point(a_plan[k])[0]
                mc.SetTransform(choice.parent, RigidTransform(p), t)
                over = bool(util_plan[k] > 1.0)
                rgb = OVER_RGB if over else OK_RGB
                choice.show(over, t, self._sphere(0.18, rgb))
            else:
                choice.show(None, t)
        a = actual_acceleration(x, self._actuation_port.Eval(context))
        if np.all(np.isfinite(a)):
            mc.SetTransform(self._actual.parent, RigidTransform(self.panel_point(a)[0]), t)
            u = float(utilisation(a, mu_limit))
            over = bool(u > 1.0)
            create = self._sphere(0.45, OVER_RGB) if over else self._sphere(0.3, (1.0, 1.0, 1.0))
            self._actual.show(over, t, create)
            self._label.show(f"utilisation {u:.1f}" if np.isfinite(u) else None, t)
        else:
            self._actual.show(None, t)
            self._label.show(None, t)
