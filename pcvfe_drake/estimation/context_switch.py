"""A switch to a context with more friction waits for confirmation (no pydrake).

The camera's context id can jump to the wrong context for a few frames: on the paper map the
gravel transition strip between patchy grass and brick looks like concrete, and on 7 of 10
``paper_eval_effects`` laps its frames took concrete's id for 0.4-0.5 s. Handing concrete's
friction there (0.6, against grass' 0.3) made the car accelerate hard; the noise hold then kept
it for another second; then brick, a terrain not seen before, got the unknown-context value and
the car, now fast, braked into a bend and left the line by ~1.6 m.

:class:`RiseGuard` makes the switch asymmetric. A switch to a context whose theta has *less*
friction than the one handed before is taken at once (the safe direction). A switch to *more*
friction is taken only once the new context has been reported for ``confirm_s`` seconds: the
first frame with its id at least ``confirm_s`` after its first one (noise frames in between do
not reset the count; another context's id does). Until then the controller keeps the theta it
had (the confirmed context's, or the unknown-context policy's when that was in use), capped at
the new context's. ``confirm_s = 0`` (the default) is the behaviour without the guard.

A real change of terrain towards more friction costs at most ``confirm_s`` of driving on the
previous, lower friction; a stray id costs nothing, because it never lasts that long.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

NOISE = -1


def check_confirm_s(value: float, where: str = "rise_confirm_s") -> None:
    """Raise ValueError naming ``where`` unless ``value`` is a number of seconds >= 0."""
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
        raise ValueError(f"{where} must be a number of seconds >= 0 (0: off), got {value!r}")


@dataclass
class RiseGuard:
    """The confirmation state (see the module docstring); held by the ``ContextEstimator``."""

    confirm_s: float = 0.0
    confirmed: int = NOISE
    """Context whose theta is handed as confirmed (-1: the unknown-context policy's)."""
    streak: int = NOISE
    """Latest context id reported (noise frames do not change it)."""
    streak_start_s: float = -math.inf
    """Time of the first sample of ``streak`` [s]."""

    def __post_init__(self) -> None:
        check_confirm_s(self.confirm_s, "RiseGuard.confirm_s")

    def observe(self, t_s: float, ident: int, handed: int) -> None:
        """One sample: ``ident`` is its context id (-1 noise), ``handed`` the context whose
        theta the estimator hands now (the held one while noise lasts at most its hold; -1: the
        unknown-context policy)."""
        if ident >= 0 and ident != self.streak:
            self.streak, self.streak_start_s = ident, t_s
        if handed < 0:
            self.confirmed = NOISE
        elif ident == self.streak and t_s - self.streak_start_s >= self.confirm_s - 1e-9:
            self.confirmed = ident

    def pending(self, handed: int) -> bool:
        """True while ``handed`` is a context switched to but not confirmed yet."""
        return self.confirm_s > 0 and handed >= 0 and handed != self.confirmed

    def limit(self, theta: np.ndarray, confirmed_theta: np.ndarray) -> np.ndarray:
        """``theta`` of a pending switch, capped by the confirmed one's friction: whichever of
        the two has less mu."""
        return confirmed_theta if confirmed_theta[0] < theta[0] else theta
