"""What the NMPC planned at its latest update, for visual debugging and logs (no solving here).

State order of the predicted states: ``pcvfe_drake.vehicle.single_track`` ([sx, sy, delta, v,
psi, psi_dot, beta]); inputs ``[steer_rate rad/s, accel m/s^2]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.vehicle.single_track import NU, NX


def _empty(*shape: int) -> np.ndarray:
    return np.zeros(shape)


@dataclass(frozen=True)
class NmpcPlan:
    """The plan of one NMPC update (never mutated).

    Attributes:
        x_pred: (N+1, 7) predicted states over the horizon, ``x_pred[0]`` the measured state;
            empty (0, 7) when the update fell back before it had a plan.
        u_pred: (N, 2) planned inputs (same: empty on a fallback without a plan).
        ref_xy: (N, 2) the reference window it tracked: the course points [m] its predicted
            positions were projected onto (stages 1..N).
        v_ref_mps: (N,) the reference speeds there (friction-limited speed profile).
        mode: ``"qp"`` (a fresh solution), ``"shifted_plan"`` or ``"braking"`` (fallbacks),
            ``"none"`` before the first update.
        reason: why the update fell back (OSQP status or error); "" when ``mode == "qp"``.
        mu_hat: friction the plan assumes.
        time_s: simulation time of the update [s] (nan when not known).
    """

    x_pred: np.ndarray = field(default_factory=lambda: _empty(0, NX))
    u_pred: np.ndarray = field(default_factory=lambda: _empty(0, NU))
    ref_xy: np.ndarray = field(default_factory=lambda: _empty(0, 2))
    v_ref_mps: np.ndarray = field(default_factory=lambda: _empty(0))
    mode: str = "none"
    reason: str = ""
    mu_hat: float = float("nan")
    time_s: float = float("nan")

    def __deepcopy__(self, memo) -> NmpcPlan:
        # Immutable (frozen, arrays never written): Drake's per-step copies of the abstract
        # state can share it.
        return self

    @property
    def is_fallback(self) -> bool:
        """Whether this update fell back (shifted plan or braking)."""
        return self.mode in ("shifted_plan", "braking")

    @property
    def has_prediction(self) -> bool:
        """Whether there are predicted states to draw."""
        return len(self.x_pred) > 1 and len(self.u_pred) == len(self.x_pred) - 1
