"""PlanView: the NMPC's mind in Meshcat, under ``/pcvfe/plan``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Meshcat, Rgba, Sphere
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from pcvfe_drake.control.plan import NmpcPlan
from pcvfe_drake.systems.meshcat_layer import ROOT, TextLabel, VisibleChoice
from pcvfe_drake.vehicle.single_track import NX, SX, SY, V
from pcvfe_drake.views.plan_geometry import SPEED_RGB, speed_bins, stride_indices

PATH = f"{ROOT}/plan"


class PlanView(LeafSystem):
    """Draws what the NMPC planned at its latest update.

    - ``/pcvfe/plan/trajectory/<i>``: the predicted positions over the horizon (every
      ``stride``-th stage, the last one always), spheres coloured by planned speed in
      ``SPEED_RGB`` bins from 0 to ``v_max_mps`` (blue slow .. red fast);
    - ``/pcvfe/plan/reference/<i>``: the reference window it tracked (the course points its
      predicted positions were projected on, every ``reference_stride``-th), small white cubes;
    - ``/pcvfe/plan/fallback``: above the car while the update fell back (shifted plan or
      braking), a red marker and the mode and reason as text.

    Stages a shorter plan does not have (a fallback without a plan) are hidden. Every change is
    keyed at the simulation time, so a Meshcat recording replays it (see
    ``pcvfe_drake.systems.meshcat_layer``).

    .. pydrake_system::

        name: PlanView
        input_ports:
        - plan
        - state

    Ports:
        plan: abstract :class:`pcvfe_drake.control.plan.NmpcPlan` (``Nmpc``'s ``plan`` output).
        state: (7) the measured ST state (places the fallback marker).

    Rate: one periodic publish every ``period_s`` (default 0.1 s); a plan already drawn (same
    ``time_s``) is not drawn again.
    """

    def __init__(
        self,
        meshcat: Meshcat,
        *,
        horizon: int,
        v_max_mps: float,
        period_s: float = 0.1,
        stride: int = 4,
        reference_stride: int = 8,
        point_radius_m: float = 0.35,
    ) -> None:
        super().__init__()
        if not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"PlanView: period_s must be > 0, got {period_s!r}")
        if not (np.isfinite(v_max_mps) and v_max_mps > 0):
            raise ValueError(f"PlanView: v_max_mps must be > 0, got {v_max_mps!r}")
        if int(horizon) < 1:
            raise ValueError(f"PlanView: horizon must be >= 1 stage, got {horizon!r}")
        self._meshcat = meshcat
        self._v_max = float(v_max_mps)
        self._radius = float(point_radius_m)
        self._stages = stride_indices(int(horizon) + 1, stride)
        self._ref_stages = stride_indices(int(horizon), reference_stride)
        self._plan_port = self.DeclareAbstractInputPort("plan", AbstractValue.Make(NmpcPlan()))
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self.DeclareInitializationPublishEvent(self._draw_static)
        self.DeclarePeriodicPublishEvent(period_sec=period_s, offset_sec=0.0, publish=self._draw)
        self._points: list[VisibleChoice] = []
        self._refs: list[VisibleChoice] = []
        self._fallback: VisibleChoice | None = None
        self._reason: TextLabel | None = None
        self._drawn_time: float | None = None

    @property
    def stages(self) -> np.ndarray:
        """Horizon stages drawn as trajectory points (0 = the measured state)."""
        return self._stages.copy()

    def _draw_static(self, context) -> None:
        mc = self._meshcat
        mc.Delete(PATH)
        self._drawn_time = None
        self._points = [
            VisibleChoice(mc, f"{PATH}/trajectory/{i:02d}") for i in range(len(self._stages))
        ]
        self._refs = [
            VisibleChoice(mc, f"{PATH}/reference/{i:02d}") for i in range(len(self._ref_stages))
        ]
        self._fallback = VisibleChoice(mc, f"{PATH}/fallback/marker")
        self._reason = TextLabel(
            mc, f"{PATH}/fallback/reason", rgb=(1.0, 0.3, 0.25), max_texts=32, height_m=1.0
        )
        mc.SetTransform(f"{PATH}/fallback/reason", RigidTransform([-2.0, 0.0, 5.5]))

    def _sphere(self, rgb) -> Callable[[str], None]:
        def create(path: str) -> None:
            self._meshcat.SetObject(path, Sphere(self._radius), Rgba(*rgb, 1.0))

        return create

    def _draw(self, context) -> None:
        plan: NmpcPlan = self._plan_port.Eval(context)
        t = context.get_time()
        if self._drawn_time is not None and plan.time_s == self._drawn_time:
            return
        self._drawn_time = plan.time_s
        mc = self._meshcat
        n_pred = len(plan.x_pred) if plan.has_prediction else 0
        bins = speed_bins(plan.x_pred[:, V], self._v_max) if n_pred else np.zeros(0, int)
        for choice, k in zip(self._points, self._stages, strict=True):
            if k < n_pred and np.all(np.isfinite(plan.x_pred[k, [SX, SY]])):
                x = plan.x_pred[k]
                mc.SetTransform(choice.parent, RigidTransform([x[SX], x[SY], 0.4]), t)
                b = int(bins[k])
                choice.show(b, t, self._sphere(SPEED_RGB[b]))
            else:
                choice.show(None, t)
        n_ref = len(plan.ref_xy) if plan.has_prediction else 0
        for choice, k in zip(self._refs, self._ref_stages, strict=True):
            if k < n_ref and np.all(np.isfinite(plan.ref_xy[k])):
                p = plan.ref_xy[k]
                mc.SetTransform(choice.parent, RigidTransform([p[0], p[1], 0.2]), t)
                choice.show("ref", t, self._ref_cube)
            else:
                choice.show(None, t)
        self._draw_fallback(plan, context, t)

    def _ref_cube(self, path: str) -> None:
        self._meshcat.SetObject(path, Box(0.3, 0.3, 0.3), Rgba(1.0, 1.0, 1.0, 0.9))

    def _draw_fallback(self, plan: NmpcPlan, context, t: float) -> None:
        mc = self._meshcat
        if plan.is_fallback:
            x = self._state_port.Eval(context)
            if np.all(np.isfinite(x[[SX, SY]])):
                mc.SetTransform(f"{PATH}/fallback", RigidTransform([x[SX], x[SY], 0.0]), t)

            def create(path: str) -> None:
                mc.SetObject(path, Box(1.2, 1.2, 1.2), Rgba(0.95, 0.1, 0.1, 1.0))
                mc.SetTransform(path, RigidTransform([0.0, 0.0, 4.0]))

            self._fallback.show("on", t, create)
            self._reason.show(f"{plan.mode}: {plan.reason}", t)
        else:
            self._fallback.show(None, t)
            self._reason.show(None, t)
