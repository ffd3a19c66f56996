"""Settings of the online per-context fitter (:class:`LiveFitConfig`): its windows, refit
budget, effect model, identifiability thresholds and handing, checked when built.

A scenario's ``fitter:`` section is read into it (``pcvfe_drake.runs.scenario``); the
estimator (``context_estimator.ContextEstimator``) only reads it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.estimation.fit_dataset import (
    DEFAULT_HORIZON,
    DEFAULT_STRIDE,
    DEFAULT_V_MIN_MPS,
    DEFAULT_X0_SMOOTHING_S,
)
from pcvfe_drake.handing.config import HandingConfig
from pcvfe_drake.handing.context_state import ModelError
from pcvfe_drake.models.effect_model import EffectModel, FitterEffect


@dataclass
class LiveFitConfig:
    """Settings of :class:`ContextEstimator`.

    Attributes:
        horizon_steps, stride_steps, min_speed_mps, x0_smoothing_s: window building
            (``pcvfe_drake.estimation.fit_dataset.build_windows``).
        fit_stiffness: fit C_Sf, C_Sr too, with Gaussian priors of ``stiffness_prior_rel``
            times their nominal values (default: mu only).
        stiffness_prior_rel: prior standard deviation of the stiffnesses, relative.
        prior_theta: the prior theta, the theta of contexts with too little data and the
            most friction any terrain is believed to have (default: the vehicle's nominal
            [mu, C_Sf, C_Sr]).
        min_windows: fewer usable windows than this: keep the prior.
        buffer_s: seconds of data kept per context, and of noise samples (at
            ``sample_period_s``; the newest of each label).
        sample_period_s: the data rate [s] (sets the buffer capacity).
        max_windows: most recent windows used per refit.
        max_iterations: Gauss-Newton iterations per refit.
        max_contexts_per_update: contexts refitted per call of ``refit`` (round-robin).
        relabel: after each re-clustering, give the stored samples the clustering's new labels
            (paper eq. 5d; the ContextFitter's ``frame_labels`` input); False: every sample keeps
            the id it was taken with (noise samples never count).
        model: the effect model (``pcvfe_drake.models.effect_model.EffectModel``: the
            effects with their held values, the model-error budget): the workbench model
            with these effects instead of the bare ST model (``effect_fit``). No effects: the
            ST fit (default). ``effects`` and ``model_error_rel`` read it.
        effect_horizon_s, effect_stride_s, effect_max_windows, effect_min_windows: the
            effect fit's windows (horizon, spacing, the newest this many per refit, fewer than
            this many: keep the prior).
        effect_incremental: refit the effect model incrementally (``incremental_fit``: the
            windows already fitted keep their information, only new windows are rolled out);
            False: every refit is the batch fit, the reference the incremental one is tested
            against.
        identifiable_std: mu's standard deviation above which a context is not identifiable.
        near_limit_fraction: the data came near the limit when the used friction reached this
            fraction of the fitted mu.
        handing: what the controller gets (``pcvfe_drake.handing``; ``docs/handing.md``).
    """

    horizon_steps: int = DEFAULT_HORIZON
    stride_steps: int = DEFAULT_STRIDE
    min_speed_mps: float = DEFAULT_V_MIN_MPS
    x0_smoothing_s: float = DEFAULT_X0_SMOOTHING_S
    fit_stiffness: bool = False
    stiffness_prior_rel: float = 0.1
    prior_theta: list[float] | None = None
    min_windows: int = 20
    buffer_s: float = 60.0
    sample_period_s: float = 0.01
    max_windows: int = 512
    max_iterations: int = 5
    max_contexts_per_update: int = 2
    relabel: bool = True
    model: EffectModel = field(default_factory=EffectModel)
    effect_horizon_s: float = 1.0
    effect_stride_s: float = 0.5
    effect_max_windows: int = 100
    effect_min_windows: int = 10
    effect_incremental: bool = True
    identifiable_std: float = 0.05
    near_limit_fraction: float = 0.6
    handing: HandingConfig = field(default_factory=HandingConfig)

    @property
    def effects(self) -> list[FitterEffect]:
        """The effect model's effects (``model.effects``)."""
        return self.model.effects

    @property
    def model_error_rel(self) -> float:
        """The effect model's model-error budget (``model.model_error_rel``)."""
        return self.model.model_error_rel

    def __post_init__(self) -> None:
        for name in ("effect_horizon_s", "effect_stride_s", "identifiable_std"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"LiveFitConfig.{name} must be > 0, got {value!r}")
        if not (0 < self.near_limit_fraction <= 1):
            raise ValueError(
                f"LiveFitConfig.near_limit_fraction must be in (0, 1], got "
                f"{self.near_limit_fraction!r}"
            )
        positive_ints = (
            "horizon_steps",
            "stride_steps",
            "min_windows",
            "max_windows",
            "max_iterations",
            "max_contexts_per_update",
            "effect_max_windows",
            "effect_min_windows",
        )
        for name in positive_ints:
            value = getattr(self, name)
            if not (isinstance(value, int | np.integer) and value >= 1):
                raise ValueError(f"LiveFitConfig.{name} must be an integer >= 1, got {value!r}")
        for name in ("buffer_s", "sample_period_s", "stiffness_prior_rel"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"LiveFitConfig.{name} must be > 0, got {value!r}")
        if not math.isfinite(self.min_speed_mps):
            raise ValueError(f"LiveFitConfig.min_speed_mps must be finite: {self.min_speed_mps!r}")
        if self.prior_theta is not None:
            prior = np.asarray(self.prior_theta, dtype=float)
            if prior.shape != (3,) or not np.all(np.isfinite(prior)) or np.any(prior <= 0):
                raise ValueError(
                    "LiveFitConfig.prior_theta must be 3 positive numbers, "
                    f"got {self.prior_theta!r}"
                )
        try:
            self.model_error()
        except ValueError as exc:
            raise ValueError(f"LiveFitConfig.{exc}") from None

    def model_error(self) -> ModelError:
        """The effect model's error budget and the frictions it was measured over: the
        calibration surface's and the checked surface's (``model.measured_mu_range``, from the
        car's model file; None: not known, the budget alone)."""
        return ModelError(self.model_error_rel, self.model.measured_mu_range)
