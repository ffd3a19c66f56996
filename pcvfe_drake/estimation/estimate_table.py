"""The per-context estimate table of the online fitter (``ContextEstimator``).

:class:`ContextEstimate` is one context's row (theta, its standard deviations, fit status and
counts, and the identifiability of mu: its lower bound from the friction the data used, whether
the data came near the limit); :class:`EstimateTable` is the table the ``ContextFitter`` outputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pcvfe_drake.estimation.probe import ProbeState
from pcvfe_drake.json_numbers import finite_or_none
from pcvfe_drake.vehicle.params import THETA_NAMES

Z95 = 1.959964
"""Two-sided 95 % quantile of the standard normal distribution."""


@dataclass(frozen=True)
class ContextEstimate:
    """The estimate of one context (one row of the estimate table).

    Attributes:
        context_id: the context id (>= 0).
        theta: [mu, C_Sf, C_Sr] in use for this context (the prior until a fit succeeded).
        theta_std: standard deviations (NaN where not fitted / not yet fitted).
        samples: samples attributed to this context: received with its id, plus those a
            relabelling moved in, minus those it moved out.
        n_windows: windows used in the last fit (0 if none).
        last_update_s: simulation time of the last successful fit [s] (NaN if none).
        first_fit_s: simulation time of the first successful fit [s] (NaN if none).
        status: "prior" (no fit yet), "too_little_data", "fitted" (converged), "fitting"
            (iteration cap reached, continues at the next update), or "diverged" (the last
            refit diverged; theta is the last good estimate).
        fits: successful fits so far.
        diverged: refits that diverged and were discarded.
        loss: loss of the last successful fit (NaN if none).
        message: a human-readable note (e.g. why the prior is used, solver warnings).
        mu_lower_bound: the largest friction the context's data used (a high quantile of
            ``sqrt(a_x^2 + a_y^2) / g`` from the measured states, the largest over its refits;
            ``pcvfe_drake.estimation.effect_fit.friction_used``): mu is at least this (NaN
            before the first refit).
        near_limit: the data came near the friction limit (``mu_lower_bound >=
            near_limit_fraction * mu``); False: a friction peak is barely observable here.
        identifiable: near_limit and mu's standard deviation at most ``identifiable_std``, not
            ``below_used`` and not ``untrusted``.
        untrusted: why the fit-quality checks say the fitted mu is not the friction
            (``fit_answer.distrust``: mu on its bound, a loss far above what the noise explains,
            a poor fit of the states friction acts on), empty where they do not: a model that
            does not explain the data does not determine its mu, however small its std.
        below_used: the fitted friction peak is below the friction the data used (impossible:
            the model's tyre law does not fit this context's data; the controller gets at
            least the used friction).
        mu_is_peak: mu is the friction peak (a fitted effect model with a peak tyre).
        model_params: the fitted effect model's parameters, ``((name, value, std), ...)``
            (empty for the ST fit).
        probe: the context's exploration state (``handing.unidentified: !Probe``; None
            otherwise).
        handing: the context's handing state (``pcvfe_drake.handing.context_state``: unknown,
            exploring, identified, backed off; empty where not set by the estimator).
        data_end_s: the newest sample time the published fit used [s] (NaN if none).
        sample_to_estimate_s: ``(p50, p99, samples)``: how long [s] the context's samples
            waited, from their time to the publication of the first fit that used them
            (samples newer than the previous fit's data that a window of the fit holds;
            ``ContextEstimator``).
        sample_to_refit_s: the same over the samples a refit published, after the context's
            first fit (the refits' cadence, without the wait for enough data for a first fit).

    The reported 95 % interval of mu is :attr:`mu_interval_95`.
    """

    context_id: int
    theta: tuple[float, float, float]
    theta_std: tuple[float, float, float]
    samples: int = 0
    n_windows: int = 0
    last_update_s: float = float("nan")
    first_fit_s: float = float("nan")
    data_end_s: float = float("nan")
    sample_to_estimate_s: tuple[float, float, int] = (float("nan"), float("nan"), 0)
    sample_to_refit_s: tuple[float, float, int] = (float("nan"), float("nan"), 0)
    status: str = "prior"
    fits: int = 0
    diverged: int = 0
    loss: float = float("nan")
    message: str = ""
    mu_lower_bound: float = float("nan")
    near_limit: bool = False
    identifiable: bool = False
    below_used: bool = False
    untrusted: str = ""
    mu_is_peak: bool = False
    model_params: tuple = ()
    probe: ProbeState | None = None
    handing: str = ""

    @property
    def mu(self) -> float:
        return self.theta[0]

    @property
    def mu_std(self) -> float:
        return self.theta_std[0]

    @property
    def mu_interval_95(self) -> tuple[float, float]:
        """The 95 % interval of mu the table reports: ``mu +- 1.96 std`` where the data came
        near the friction limit; where they never did, the one-sided ``[mu_lower_bound, inf)``
        (the car used that much friction, and nothing in the data bounds the peak from above:
        a two-sided interval around such a fit would be a confident wrong number). (NaN, NaN)
        before a fit or without a std."""
        if not self.fitted:
            return (math.nan, math.nan)
        if not self.near_limit and math.isfinite(self.mu_lower_bound):
            return (self.mu_lower_bound, math.inf)
        std = self.mu_std
        if math.isnan(std):
            return (math.nan, math.nan)
        return (self.mu - Z95 * std, self.mu + Z95 * std)

    @property
    def fitted(self) -> bool:
        """A fit has succeeded at least once (theta is an estimate, not the prior)."""
        return self.fits > 0

    def to_dict(self) -> dict:
        return {
            "context_id": self.context_id,
            "theta": dict(zip(THETA_NAMES, map(finite_or_none, self.theta), strict=True)),
            "std": dict(zip(THETA_NAMES, map(finite_or_none, self.theta_std), strict=True)),
            "samples": self.samples,
            "n_windows": self.n_windows,
            "last_update_s": finite_or_none(self.last_update_s),
            "first_fit_s": finite_or_none(self.first_fit_s),
            "status": self.status,
            "fits": self.fits,
            "diverged": self.diverged,
            "loss": finite_or_none(self.loss),
            "message": self.message,
            "mu_lower_bound": finite_or_none(self.mu_lower_bound),
            "near_limit": self.near_limit,
            "identifiable": self.identifiable,
            "below_used": self.below_used,
            "untrusted": self.untrusted or None,
            # None: no bound / unknown
            "mu_interval_95": [finite_or_none(v) for v in self.mu_interval_95],
            "mu_is_peak": self.mu_is_peak,
            "probe": None if self.probe is None else self.probe.to_dict(),
            "handing": self.handing,
            "model_params": {
                n: {"value": finite_or_none(v), "std": finite_or_none(sd)}
                for n, v, sd in self.model_params
            },
        }


@dataclass(frozen=True)
class EstimateTable:
    """Per-context estimates at ``time_s``, with the prior used for noise/unknown contexts."""

    entries: tuple[ContextEstimate, ...] = ()
    prior_theta: tuple[float, float, float] = (float("nan"),) * 3
    time_s: float = float("nan")
    rejected_samples: int = 0
    noise_samples: int = 0
    relabelled_samples: int = 0
    labels_version: int = 0

    def get(self, context_id: int) -> ContextEstimate | None:
        for entry in self.entries:
            if entry.context_id == context_id:
                return entry
        return None

    def to_dict(self) -> dict:
        return {
            "time_s": self.time_s if math.isfinite(self.time_s) else None,
            "prior_theta": dict(zip(THETA_NAMES, self.prior_theta, strict=True)),
            "rejected_samples": self.rejected_samples,
            "noise_samples": self.noise_samples,
            "relabelled_samples": self.relabelled_samples,
            "labels_version": self.labels_version,
            "entries": [e.to_dict() for e in self.entries],
        }
