"""What PC-VFE hands the controller while it does not know the terrain (no pydrake).

The friction estimate is unknown while the camera frame is noise (a new terrain waits for the
next re-clustering; a stray frame) for longer than ``noise_hold_s``, or while the current
context has no fit yet (too little data). The policy decides the friction used meanwhile:

* ``prior``: the prior theta (the vehicle's nominal mu, 1.05 for the Ford Escort): optimistic
  on every terrain of the paper's map; the behaviour before this choice existed.
* ``last_known``: the estimate of the last context that had one (the prior if none yet): right
  while the car is still on the terrain it came from, wrong by the full step after a transition.
* ``conservative`` (default): the lowest lower confidence bound ``mu - sigmas * std`` over the
  contexts fitted so far (for a friction peak, never below the friction that context's data
  used: a peak the data never approached has a huge std, and ``mu - sigmas * std`` would say
  "no grip" about a terrain the car has just driven on), and never above ``floor_mu`` (the
  lowest friction the operator expects on the course; 0.3 by default, the paper map's patchy
  grass). Safe by construction: slower on
  a new terrain until it has its own fit. With ``floor_stated`` the floor is the operator's
  stated lowest friction of the course (a scenario setting, not something learned from the
  map): no terrain is expected below it, so the value never goes below it either and is the
  floor itself. This is what ``unidentified_mu: probe`` already assumes of every fitted
  context: an identifiable estimate is never handed below the floor, and the probe starts there
  (``pcvfe_drake.estimation.probe.controller_theta``). Without it, a context fitted low (the
  public mapping's grass, 0.26 +- 0.03 for 0.30 on `paper_eval_effects`) sets a value (0.22)
  below anything handed on any terrain, and a new terrain after it (brick, 0.80) was driven
  5.5 s at 0.22 before its id (seed 0).

``prior`` and ``last_known`` hand over a whole theta. ``conservative`` lowers the friction limit
only: in the single-track model the tyre's small-slip stiffness is ``mu * C_S``, so its C_Sf,
C_Sr are the prior's scaled by ``prior_mu / mu`` (the prior's stiffness kept). Lowering mu alone
would tell the NMPC that the tyres are softer than they are: it steers too much, and on the
default lap the lateral error RMS doubled (0.012 -> 0.024 m, 0.057 m while the policy was in
use; docs/friction_sources.md).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

UNKNOWN_CONTEXT_POLICIES = ("prior", "last_known", "conservative")
DEFAULT_POLICY = "conservative"
DEFAULT_FLOOR_MU = 0.3
DEFAULT_SIGMAS = 2.0


def check_policy(policy: str, floor_mu: float, sigmas: float, where: str = "policy") -> None:
    """Raise ValueError naming ``where`` when the policy or its numbers are invalid."""
    if policy not in UNKNOWN_CONTEXT_POLICIES:
        raise ValueError(f"{where}: unknown_context={policy!r}; choose {UNKNOWN_CONTEXT_POLICIES}")
    if not (math.isfinite(floor_mu) and floor_mu > 0):
        raise ValueError(f"{where}: unknown_floor_mu={floor_mu!r} must be > 0")
    if not (math.isfinite(sigmas) and sigmas >= 0):
        raise ValueError(f"{where}: unknown_sigmas={sigmas!r} must be >= 0")


def unknown_context_theta(
    policy: str,
    prior_theta,
    fitted: Iterable[tuple[float, float]],
    last_known_theta=None,
    *,
    floor_mu: float = DEFAULT_FLOOR_MU,
    sigmas: float = DEFAULT_SIGMAS,
    keep_stiffness: bool = True,
    floor_stated: bool = False,
) -> np.ndarray:
    """theta [mu, C_Sf, C_Sr] to use while the context is unknown.

    Args:
        policy: one of ``UNKNOWN_CONTEXT_POLICIES``.
        prior_theta: the prior (3,).
        fitted: ``(mu, mu_std)`` or ``(mu, mu_std, used)`` of every context fitted so far (std
            NaN: treated as 0; ``used``: the friction its data used, a floor on its lower
            confidence bound; NaN or absent: none).
        last_known_theta: theta of the last context with an estimate (None: none yet).
        floor_mu: ``conservative``'s upper limit on mu.
        sigmas: ``conservative``'s confidence multiplier.
        floor_stated: ``floor_mu`` is the operator's stated lowest friction: ``conservative``
            never goes below it (it hands the floor).
        keep_stiffness: ``conservative`` keeps the prior's small-slip stiffness ``mu * C_S``
            (C_S scaled by ``prior_mu / mu``); False: the prior's C_Sf, C_Sr as they are (the
            behaviour before; the NMPC then believes softer tyres).
    """
    theta = np.array(prior_theta, dtype=float).reshape(3)
    if policy == "prior":
        return theta
    if policy == "last_known":
        if last_known_theta is None:
            return theta
        return np.array(last_known_theta, dtype=float).reshape(3)
    if policy != "conservative":
        raise ValueError(f"unknown_context={policy!r}; choose {UNKNOWN_CONTEXT_POLICIES}")
    mu = float(floor_mu)
    for entry in fitted:
        m, std = entry[0], entry[1]
        used = entry[2] if len(entry) > 2 else math.nan
        if math.isfinite(m):
            lcb = m - sigmas * (std if math.isfinite(std) else 0.0)
            if math.isfinite(used):
                lcb = max(lcb, used)
            mu = min(mu, lcb)
    mu = max(mu, float(floor_mu) if floor_stated else 0.05)
    # The single-track tyre's small-slip stiffness is mu * C_S: keep the prior's, so that only
    # the friction limit is lowered (a lower mu alone would also tell the controller that the
    # tyres are softer than they are; it then steers too much: docs/friction_sources.md).
    if keep_stiffness:
        return with_friction(theta, mu)
    theta[0] = mu
    return theta


def with_friction(theta, mu: float) -> np.ndarray:
    """``theta = [mu, C_Sf, C_Sr]`` with the friction ``mu`` and the single-track tyre's
    small-slip stiffness ``mu * C_S`` kept (C_Sf, C_Sr scaled by ``theta[0] / mu``): only the
    friction limit moves. A new array."""
    theta = np.array(theta, dtype=float)
    theta[1:] *= theta[0] / mu
    theta[0] = mu
    return theta
