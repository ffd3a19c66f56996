"""One context's handing: its state (unknown, exploring, identified, backed off) and the theta it
is handed (no pydrake).

The fitter says what the data say (``ContextEstimate``: the estimate, its std, identifiable or
not); these rules decide what the controller gets for it:

* no fit yet: **unknown** (the unknown-context value, ``pcvfe_drake.handing.unknown``), or
  with ``!Probe`` and a stated floor, once its visit is confirmed, **exploring** from its
  first samples (``Handing.probes_before_fit``: the probe reads the tyres, not the fit);
* identifiable: **identified**, handed its own estimate, also below the stated floor (the floor
  is an operator's guess, the fit a measurement), less the model error that grows away from the
  frictions the effect model was calibrated at (:class:`ModelError`), but never less than the
  friction its data used (the car drove it without sliding: a measured lower bound, whatever
  the model's error);
* not identifiable: **exploring** (``!Probe``: the probe's level, at most the upper end of the
  fit's 95 % interval; ``!LowerBound``: the friction the data used, at least the floor, at most
  the fit; ``!Estimate``: the fit), or **backed off** while the probe's last move was a
  back-off;
* a friction peak fitted below the friction its data used is impossible: it is raised to it.

The stiffnesses are always scaled to keep the fit's small-slip stiffness ``mu * C_S``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.estimation.probe import ProbeState
from pcvfe_drake.handing.config import Estimate, LowerBound, Probe
from pcvfe_drake.handing.unknown import with_friction

UNKNOWN = "unknown"
EXPLORING = "exploring"
IDENTIFIED = "identified"
BACKED_OFF = "backed_off"
STATES = (UNKNOWN, EXPLORING, IDENTIFIED, BACKED_OFF)

Z_95 = 1.96
"""The normal quantile of a two-sided 95 % interval."""


@dataclass(frozen=True)
class ModelError:
    """The effect model's own error, relative to mu, and where it was calibrated.

    ``rel`` is the budget the fitter adds to mu's std (``EffectModel.model_error_rel``), valid
    over the frictions ``calibrated_mu = (low, high)`` the model's held constants were found at
    (from a one-surface calibration ``low == high``, ``EffectModel.calibrated_mu``).
    Beyond them the error is assumed to grow in proportion to the distance, ``rel * max(mu /
    high, low / mu)``: a constant fitted at one friction says nothing about the sign of its
    error at another, so the handing hands an identified estimate less what the growth adds to
    the error's 95 % bound (:meth:`handed_mu`), and an over-estimate there is not handed as
    certain. ``calibrated_mu`` None: no growth is known (the budget alone).

    The error is a bias of the held model (the same at the same friction), bounded by ``rel``
    inside the calibrated frictions and by the grown ``rel`` outside; the bound grows, so the
    margin grows with it, linearly: the handed value stays as far above the grown bound's 95 %
    lower end as an estimate inside is above the budget's. It is continuous in the estimate
    with its slope, so the handed mu rises with the estimate on both sides of the calibrated
    frictions (a quadrature sum of a budget and an independent grown part would have an
    infinite slope at their ends: a little outside would cost far more than the growth, and a
    higher estimate just above ``high`` would be handed less than one at ``high``).
    """

    rel: float = 0.0
    calibrated_mu: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rel) and self.rel >= 0):
            raise ValueError(f"ModelError.rel must be >= 0, got {self.rel!r}")
        cal = self.calibrated_mu
        if cal is not None:
            ok = len(cal) == 2 and all(math.isfinite(v) and v > 0 for v in cal)
            if not (ok and cal[0] <= cal[1]):
                raise ValueError(
                    "model_calibrated_mu must be [low, high] with 0 < low <= high, got "
                    f"{list(cal)!r}"
                )
            object.__setattr__(self, "calibrated_mu", (float(cal[0]), float(cal[1])))

    def rel_at(self, mu: float) -> float:
        """The relative model error at ``mu``: ``rel`` inside the calibrated frictions, growing
        in proportion to the distance outside them."""
        if self.calibrated_mu is None or not (math.isfinite(mu) and mu > 0):
            return self.rel
        low, high = self.calibrated_mu
        return self.rel * max(mu / high, low / mu, 1.0)

    def extra_std(self, mu: float) -> float:
        """What the growth adds [-] to the budget's error bound at ``mu`` (``mu * (rel_at(mu) -
        rel)``): 0 inside the calibrated frictions."""
        return mu * max(self.rel_at(mu) - self.rel, 0.0)

    def handed_mu(self, mu: float) -> float:
        """An identified estimate ``mu`` as handed: less what the growth adds to the error's
        95 % bound."""
        return mu - Z_95 * self.extra_std(mu)


@dataclass
class ContextHanding:
    """One context's handing state, kept by ``Handing`` beside the fitter's estimate."""

    probe: ProbeState = field(default_factory=ProbeState)
    """The exploration state (``!Probe``)."""
    handed_fit_mu: float = math.nan
    """The largest mu its latest identified spell handed (NaN: none, or over a hold ago)."""
    handed_fit_end_s: float = math.nan
    """When that spell ended (NaN: still handed) [s]."""


def context_state(estimate, probe: ProbeState) -> str:
    """The state of a context with the fitter's ``estimate`` (a ``ContextEstimate``) and its
    ``probe``."""
    if not estimate.fitted and not probe.started:
        return UNKNOWN
    if estimate.fitted and estimate.identifiable:
        return IDENTIFIED
    return BACKED_OFF if probe.backed_off else EXPLORING


def handed_theta(
    estimate,
    probe: ProbeState,
    theta: np.ndarray,
    policy,
    floor_mu: float,
    model_error: ModelError = ModelError(),
) -> np.ndarray:
    """The theta the controller gets for a fitted context (``estimate``, its fit's ``theta``;
    ``policy``: ``HandingConfig.unidentified``; see the module docstring)."""
    mu = float(theta[0])
    bound = estimate.mu_lower_bound if math.isfinite(estimate.mu_lower_bound) else 0.0
    if estimate.below_used:
        mu = max(mu, bound)
    if estimate.identifiable:
        # the grown model error never takes it below the friction the car demonstrated there
        mu = max(model_error.handed_mu(mu), bound)
    elif isinstance(policy, LowerBound):
        cap = math.inf if estimate.below_used else mu
        mu = min(max(bound, floor_mu), cap)
    elif isinstance(policy, Probe):
        # at most the upper end of the fit's 95 % interval (a value its data do not exclude),
        # never below the floor where the probe starts; a fit below the friction used or whose
        # peak the data do not show (``untrusted``) excludes nothing above it
        std = estimate.mu_std
        bounded = math.isfinite(std) and not (estimate.below_used or estimate.untrusted)
        cap = mu + Z_95 * std if bounded else math.inf
        start = probe.mu if probe.started else max(bound, floor_mu)
        mu = min(start, max(cap, floor_mu))
    elif not isinstance(policy, Estimate):
        raise ValueError(f"HandingConfig.unidentified: unknown policy {policy!r}")
    mu = max(mu, 0.05)
    if mu == theta[0]:
        return np.array(theta, dtype=float)
    return with_friction(theta, mu)
