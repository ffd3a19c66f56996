"""Tyre effects that see the vehicle state: friction that changes with speed or axle load.

They use the ``friction`` hook of :class:`~pcvfe_drake.workbench.effects.Effect`: a factor on
the friction coefficient of one axle, computed from the state (``ctx.x``) and that axle's
load. The factor scales the cornering stiffness ``mu C_S Fz`` and, with ``tire_saturation``,
the force peak.

* ``friction_speed``: ``mu(v) = mu (1 - k_v (v - V_REF))``, friction that falls (k_v > 0) or
  rises with speed, as on wet roads;
* ``friction_load``: ``mu(Fz) = mu (1 - k_z (Fz / Fz_static - 1))``, the degressive load
  sensitivity of a real tyre (k_z > 0: a loaded axle grips less per newton).
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.workbench.effects import Effect, EffectParam, register_effect

V_REF_MPS = 15.0
"""Speed at which ``friction_speed`` leaves mu unchanged [m/s]."""
MIN_FACTOR = 0.05
"""Smallest friction factor (keeps the tyre law defined for extreme parameters)."""


class FrictionSpeed(Effect):
    """Friction that changes linearly with speed: ``mu (1 - k_v (v - 15 m/s))``."""

    name = "friction_speed"
    description = "speed-dependent friction, mu(v) = mu (1 - k_v (v - 15 m/s))"
    params = (
        EffectParam("k_v", "s/m", -0.06, 0.06, 0.0, 0.005, 0.0, "relative friction loss per m/s"),
    )
    signature_state = "psi_dot"
    signature_label = "(v - 15 m/s) x lateral acceleration"

    def friction(self, fz, ctx, p):
        return np.maximum(1.0 - p["k_v"] * (ctx.x[:, 3] - V_REF_MPS), MIN_FACTOR)

    def signature_regressors(self, data):
        v = data.x[:, 3]
        return ((v - V_REF_MPS) * v * data.x[:, 5])[:, None]


class FrictionLoad(Effect):
    """Load-sensitive friction: ``mu (1 - k_z (Fz / Fz_static - 1))`` per axle."""

    name = "friction_load"
    description = "load-dependent friction, mu(Fz) = mu (1 - k_z (Fz / Fz_static - 1))"
    params = (EffectParam("k_z", "-", -1.5, 1.5, 0.0, 0.05, 0.0, "load sensitivity"),)
    signature_state = "psi_dot"
    signature_label = "longitudinal x lateral acceleration"

    def friction(self, fz, ctx, p):
        rel = fz / max(ctx.fz_static, 1.0) - 1.0
        return np.maximum(1.0 - p["k_z"] * rel, MIN_FACTOR)

    def signature_regressors(self, data):
        return (data.u[:, 1] * data.x[:, 3] * data.x[:, 5])[:, None]


for _cls in (FrictionSpeed, FrictionLoad):
    register_effect(_cls)
