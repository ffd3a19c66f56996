"""Tyre effects that see the vehicle state: friction that changes with speed or axle load.

They use the ``friction`` hook of :class:`~pcvfe_drake.workbench.effects.Effect`: a factor on
the friction coefficient of one axle, computed from the state (``ctx.x``) and that axle's
load. The factor scales the cornering stiffness ``mu C_S Fz`` and, with ``tire_saturation``,
the force peak.

* ``friction_speed``: ``mu(v) = mu (1 - k_v (v - V_REF))``, friction that falls (k_v > 0) or
  rises with speed, as on wet roads;
* ``friction_load``: ``mu(Fz) = mu (1 - k_z (Fz / Fz_static - 1))``, the degressive load
  sensitivity of a real tyre (k_z > 0: a loaded axle grips less per newton).

And one tyre law that uses the ``tire`` hook:

* ``peak_tyre``: a Pacejka magic-formula lateral tyre with which the base ``mu`` IS the
  friction peak (``friction_is_peak``), its small-slip stiffness following the friction level
  by an exponent (see :class:`PeakTyre`).
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


MF_SHAPE = 1.35
"""Magic-formula shape factor C of ``peak_tyre`` [-]: CommonRoad's Ford Escort tyre has
p_cy1 = 1.3507 (Pacejka gives C ~ 1.3 for the lateral force of passenger-car tyres)."""


class PeakTyre(Effect):
    """Magic-formula lateral tyre with the friction as its peak (base ``mu`` = the peak).

    Per axle, with ``mu_a = mu x`` the axle's friction factors (``friction`` hooks) and load
    ``Fz``::

        D   = mu_a Fz                                      peak force [N]
        K   = C_S Fz mu_nom (mu / mu_nom)^k_s x factors     small-slip stiffness [N/rad]
        F_y = D sin(C atan(K alpha / (C D)))               C = MF_SHAPE = 1.35

    (Pacejka's simplified lateral law with curvature E = 0, as CommonRoad's multi-body tyre
    whose E is -0.007.) For ``C >= 1`` the largest force is exactly ``D``: base mu is the
    largest lateral force / Fz of an axle (``friction_is_peak``), reached at the slip
    ``tan(pi / (2 C)) C D / K``; beyond it the force falls towards ``D sin(C pi / 2)`` (0.85 D).
    ``mu_nom`` is the vehicle's nominal mu (``VehicleParams.mu``) and ``C_S`` its cornering
    stiffness; the exponent ``k_s`` says how much of the stiffness follows the friction level:
    ``k_s = 1`` stiffness proportional to mu (CommonRoad's friction mapping
    ``peak_and_stiffness``; then for small slip ``F_y = mu C_S Fz alpha``, the baseline's
    linear tyre), ``k_s = 0`` stiffness independent of mu (the public PC-VFE simulator's
    ``lateral_peak``: only the peak changes with the terrain).

    The shape factor is fixed, not fitted: fitted by multi-step prediction error it runs to
    its bound C = 1 on planted magic-formula data (C = 1.35, peak 0.6-0.8), dragging the
    peak 10-20 % high, because beyond the peak the true car is unstable and a flatter
    law predicts noisy windows with less error; with C fixed the peak comes back within 5 %
    (see tests/test_workbench_peak_tyre.py). A user with another tyre subclasses and sets
    ``shape``.

    The effect has no null point (friction is the peak whatever ``k_s``); the null value
    given (k_s = 1) is the baseline's stiffness law. Residual signature: the yaw-rate residual
    grows with the cube of the lateral acceleration (the force falls short of the linear law
    near the peak).
    """

    name = "peak_tyre"
    description = (
        "magic-formula tyre, friction = the peak: F_y = mu Fz sin(C atan(K alpha / (C mu Fz))), "
        "K = C_S Fz mu_nom (mu / mu_nom)^k_s, C = 1.35"
    )
    params = (
        EffectParam("k_s", "-", -1.0, 2.0, 1.0, 0.1, 1.0, "exponent: how the stiffness follows mu"),
    )
    shape: float = MF_SHAPE
    friction_is_peak = True
    signature_state = "psi_dot"
    signature_label = "lateral acceleration cubed"
    starts = ((1.0,), (0.0,), (0.5,))

    def tire(self, alpha, fz, c_alpha, p, ctx):
        mu = np.maximum(np.asarray(ctx.mu, dtype=float), 1e-6)
        peak = mu * ctx.mu_scale * np.maximum(fz, 1.0)
        stiffness = c_alpha * (ctx.vehicle.mu / mu) ** (1.0 - p["k_s"])
        return peak * np.sin(self.shape * np.arctan(stiffness * alpha / (self.shape * peak)))

    def stiffness_mu(self, mu, vehicle, p):
        mu = np.maximum(np.asarray(mu, dtype=float), 1e-6)
        return vehicle.mu * (mu / vehicle.mu) ** p["k_s"]

    def signature_regressors(self, data):
        ay = data.x[:, 3] * data.x[:, 5]
        return (ay**3)[:, None]


for _cls in (FrictionSpeed, FrictionLoad, PeakTyre):
    register_effect(_cls)
