"""What the controller gets while it does not know the terrain (no pydrake).

The terrain is unknown on a noise frame (a new terrain waits for the next re-clustering; a stray
frame) and on a context with no fit yet. The policy (``HandingConfig.unknown``) decides the
friction meanwhile:

* ``!StatedFloor``: the operator's stated lowest friction ``floor_mu``, or the lowest friction
  handed to a context identified below it: the floor is a guess, and a terrain measured lower
  says the course has less.
* ``!Conservative``: the lowest lower confidence bound ``mu - sigmas * std`` over the contexts
  fitted so far (a friction peak never below the friction its data used: a peak the data never
  approached has a huge std, and the bound would say "no grip" about a terrain just driven on),
  at most ``floor_mu``.
* ``!Prior``: the prior theta; ``!LastKnown``: the last fitted context's theta.

In the single-track model the tyre's small-slip stiffness is ``mu * C_S``; the handed C_Sf, C_Sr
give it the stiffness the car's model states for that friction (:func:`with_friction`): the
prior's stiffness times ``(mu / prior_mu)^k_s`` (``k_s``: ``peak_tyre``'s stiffness law, 0 for
the shipped ``lateral_peak`` models and the bare single-track model, so only the friction limit
moves; 1 where the whole tyre follows the friction). Lowering mu alone would tell the NMPC that
the tyres are softer than they are, and it would steer too much; keeping the stiffness of a
tyre that follows the friction would tell it they are stiffer, and a probe judging slip angles
by it would read a soft tyre's larger slips as saturation.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from pcvfe_drake.handing.config import Conservative, LastKnown, Prior, StatedFloor

MIN_MU = 0.05
"""The least mu ever handed (keeps the NMPC's speed profile defined)."""


def with_friction(theta, mu: float, stiffness_law: float = 0.0) -> np.ndarray:
    """``theta = [mu, C_Sf, C_Sr]`` at the friction ``mu``, its small-slip stiffness ``mu * C_S``
    times ``(mu / theta[0])^stiffness_law`` (0: kept, only the friction limit moves). A new
    array."""
    theta = np.array(theta, dtype=float)
    ratio = theta[0] / mu
    theta[1:] *= ratio if stiffness_law == 0.0 else ratio ** (1.0 - stiffness_law)
    theta[0] = mu
    return theta


def unknown_theta(
    policy,
    prior_theta,
    floor_mu: float,
    fitted: Iterable[tuple[float, float, float]] = (),
    identified_mu: Iterable[float] = (),
    last_known_theta=None,
    stiffness_law: float = 0.0,
) -> np.ndarray:
    """theta [mu, C_Sf, C_Sr] while the context is unknown.

    Args:
        policy: a ``HandingConfig.unknown`` variant.
        prior_theta: the prior (3,).
        floor_mu: ``HandingConfig.floor_mu``.
        fitted: ``(mu, mu_std, used)`` of every fitted context (``!Conservative``; std NaN: 0;
            ``used``: a floor on the context's lower bound, NaN: none).
        identified_mu: the mu handed to every identified context (``!StatedFloor``).
        last_known_theta: the last fitted context's theta (``!LastKnown``; None: none yet).
        stiffness_law: how the small-slip stiffness follows the friction (:func:`with_friction`).
    """
    theta = np.array(prior_theta, dtype=float).reshape(3)
    if isinstance(policy, Prior):
        return theta
    if isinstance(policy, LastKnown):
        return theta if last_known_theta is None else np.array(last_known_theta, float).reshape(3)
    mu = float(floor_mu)
    if isinstance(policy, StatedFloor):
        for m in identified_mu:
            if math.isfinite(m):
                mu = min(mu, m)
    elif isinstance(policy, Conservative):
        for m, std, used in fitted:
            if math.isfinite(m):
                lcb = m - policy.sigmas * (std if math.isfinite(std) else 0.0)
                mu = min(mu, max(lcb, used) if math.isfinite(used) else lcb)
    else:
        raise ValueError(f"HandingConfig.unknown: unknown policy {policy!r}")
    return with_friction(theta, max(mu, MIN_MU), stiffness_law)
