"""The workbench model's RK4 rollout compiled (numba): the same arithmetic, row by row.

A refit rolls the model out over a handful of windows, where the numpy right-hand side
(:meth:`~pcvfe_drake.models.model.WorkbenchModel.rhs`) costs numpy's per-call overhead (about
150 calls per evaluation, 400 evaluations per rollout), not its arithmetic. This module runs
the whole RK4 loop of :meth:`~pcvfe_drake.models.model.WorkbenchModel.simulate` in one
compiled function (:mod:`pcvfe_drake.models.compiled_kernel`) for the base model and the
effects it knows (:data:`COMPILED_EFFECTS`: the effects of the shipped vehicle models and the
library's other effects that change the right-hand side), with each expression written in the
numpy code's order of operations, so that the two paths give the same numbers: to the last
bit where both call the same library functions (``sin``, ``cos``, ``atan``, ``atan2``,
``pow``, ``exp``, ``log1p``), within a few units in the last place where numpy has its own
vectorised function (``tanh``: ``roll_camber``, ``wheel_camber``, ``rolling_resistance``);
``tests/models/test_compiled_rollout.py`` compares them.

Beside each expression of the right-hand side stands its derivative along the row's base
``mu`` (forward mode), so the same loop can carry the states' exact sensitivity to mu through
the RK4 steps (``WorkbenchModel.mu_sensitivity``: the derivative of the discrete rollout that
central differences approximate). The derivatives never feed the values: a rollout without
them gives the same numbers.

A model with any other effect that changes the right-hand side (its own hooks, states, or a
subclass of a known effect) is rolled out by the numpy code; hooks outside the RK4 loop
(``inputs``, ``measure``, ``unmeasure``) stay in numpy either way. Without numba the numpy
code runs. The compiled function is cached on disk (``cache=True``): a process compiles it
once per installation, later ones load it. It releases the GIL (``nogil``), so a refit in a
worker thread does not hold up the loop's thread.
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.models import chassis_effects, effects, tyre_effects
from pcvfe_drake.models.compiled_kernel import (
    CHAINS,
    KERNEL_EFFECTS,
    N_CONSTANTS,
    numba,
    rollout_rows,
)

COMPILED_EFFECTS = KERNEL_EFFECTS
"""Effects the compiled rollout evaluates (their registered classes exactly)."""

_CLASSES = {
    cls.name: cls
    for module in (effects, tyre_effects, chassis_effects)
    for cls in vars(module).values()
    if isinstance(cls, type) and issubclass(cls, effects.Effect) and cls.name in KERNEL_EFFECTS
}
_VEHICLE_FIELDS = (
    "delta_min",
    "delta_max",
    "delta_dot_min",
    "delta_dot_max",
    "v_switch",
    "a_max",
    "v_min",
    "v_max",
    "lf",
    "lr",
    "h",
    "m",
    "g",
    "I_z",
    "mu",
)


def compiled_effect_plan(model_effects, vehicle) -> dict | None:
    """How the kernel rolls out a model with these effects (in the model's order) on this
    ``vehicle`` (``VehicleParams``), or None when its right-hand side needs the numpy code:
    numba is missing, or an effect that changes the right-hand side (its hooks, own states) is
    not one of :data:`COMPILED_EFFECTS`' classes exactly (a subclass may change any hook or
    constant). The plan holds the effects' codes in the model's order (hooks several effects
    share compose in it), each effect's first parameter column and first own state (-1: none),
    and the kernel's constants vector (:func:`constants`), all fixed for the model."""
    if numba is None:
        return None
    hooks = (*effects.RHS_HOOKS, "state_rates", "states_at")
    order, names = [], []
    col = np.full(len(KERNEL_EFFECTS), -1, dtype=np.int64)
    off = np.full(len(KERNEL_EFFECTS), -1, dtype=np.int64)
    n_cols, state = 0, 7
    for e in model_effects:
        if _CLASSES.get(e.name) is type(e):
            code = KERNEL_EFFECTS.index(e.name)
            order.append(code)
            names.append(e.name)
            col[code] = n_cols
            n_cols += len(e.params)
            if e.n_states:
                off[code] = state
        elif e.n_states or any(
            getattr(type(e), h) is not getattr(effects.Effect, h) for h in hooks
        ):
            return None
        state += e.n_states
    chains = np.full((len(CHAINS), max(len(order), 1)), -1, dtype=np.int64)
    for row, members in enumerate(CHAINS.values()):
        codes = [c for c in order if KERNEL_EFFECTS[c] in members]
        chains[row, : len(codes)] = codes
    return {
        "chains": chains,
        "col": col,
        "off": off,
        "names": names,
        "constants": constants(vehicle, model_effects),
    }


def load(model, plan: dict) -> None:
    """Compile the rollout, or load it from the disk cache, now (a tiny rollout of ``model``,
    whose :func:`compiled_effect_plan` is ``plan``) instead of in the first refit: a loop that
    starts with it loaded never waits for numba."""
    theta = np.atleast_2d(model.initial_theta())
    base, eff = model._unpack(theta, np.zeros(1, dtype=int))
    Z = np.zeros((1, 2, model.nz))
    Z[0, 0, 3] = 5.0
    rollout(Z, np.zeros((1, 1, 2)), 1, 0.01, base, eff, plan)


def constants(vp, model_effects) -> np.ndarray:
    """The vehicle's parameters and the constants of the model and its effects (the kernel's
    ``vv``), passed at run time (a compiled function's globals would be frozen into its disk
    cache)."""
    shape = next((e.shape for e in model_effects if e.name == "peak_tyre"), tyre_effects.MF_SHAPE)
    fixed = [
        effects.V_FLOOR_MPS,
        shape,
        tyre_effects.ROLL_SIGN_WIDTH_MPS2,
        chassis_effects.MAX_LOAD_SHIFT,
        effects.RHO_AIR_KGPM3,
        tyre_effects.V_REF_MPS,
        tyre_effects.MIN_FACTOR,
        tyre_effects.WHEEL_SIGN_WIDTH_MPS2,
        effects.SIGN_WIDTH_MPS,
        effects.POWER_WIDTH_MPS2,
        effects.POWER_V_MIN_MPS,
        chassis_effects.TAU_MIN_S,
        tyre_effects.ROLL_TAU_MIN_S,
    ]
    out = np.array([float(getattr(vp, f)) for f in _VEHICLE_FIELDS] + fixed)
    assert out.size == N_CONSTANTS
    return out


def rollout(Z, U, substeps: int, h: float, base: dict, eff: dict, plan: dict, S=None):
    """Fill ``Z[:, 1:]`` (N, horizon + 1, nz) from ``Z[:, 0]`` under inputs ``U`` (N,
    horizon, 2): RK4 with ``substeps`` steps of ``h`` seconds per sample step, as
    :meth:`WorkbenchModel.simulate`'s loop; ``base`` and ``eff`` as its ``_unpack``. With
    ``S`` (N, horizon + 1, 7), ``S[:, 0]`` the start's, also fill ``S[:, 1:]`` with the
    ST states' derivatives along each row's base mu (forward mode through the same RK4
    steps)."""
    n = Z.shape[0]
    cols = [eff[name][q.name] for name in plan["names"] for q in _CLASSES[name].params]
    params = np.ascontiguousarray(np.stack(cols, axis=1) if cols else np.zeros((n, 1)))
    rollout_rows(
        Z,
        np.zeros((0, 1, 7)) if S is None else S,
        np.ascontiguousarray(U, dtype=float),
        int(substeps),
        float(h),
        plan["constants"],
        np.ascontiguousarray(base["mu"], dtype=float),
        np.zeros(n) if S is None else np.ones(n),
        np.ascontiguousarray(base["C_Sf"], dtype=float),
        np.ascontiguousarray(base["C_Sr"], dtype=float),
        params.astype(float, copy=False),
        plan["chains"],
        plan["col"],
        plan["off"],
    )
