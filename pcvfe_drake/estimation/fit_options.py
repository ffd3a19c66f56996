"""Options and results of a friction fit: :class:`FitOptions`, :class:`FitResult`, the
parameter bounds, the residual scales and the status names (see ``docs/fitting.md``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.json_numbers import finite_or_none
from pcvfe_drake.vehicle.params import THETA_NAMES, VehicleParams
from pcvfe_drake.vehicle.single_track import NTHETA

DEFAULT_STATE_SCALES = (0.02, 0.02, 0.002, 0.05, math.radians(0.5), 0.01, 0.005)
"""Residual scales per state [sx m, sy m, delta rad, v m/s, psi rad, psi_dot rad/s, beta rad]:
typical measurement noise standard deviations (RTK GNSS position, steering encoder, speed,
dual-antenna heading, MEMS gyro, slip sensor). Residuals are divided by them."""

MU_BOUNDS = (0.02, 2.0)
"""Physical range of the tire-road friction coefficient (ice ~0.05 to racing slicks ~1.8)."""
STIFFNESS_REL_BOUNDS = (0.2, 5.0)
"""Range of the normalised cornering stiffnesses, relative to the vehicle's nominal values."""

MAX_STEP_S = 0.01
"""Longest RK4 step of a rollout [s]; longer data steps (e.g. a 10 Hz log) are integrated in equal
substeps with the input held. The ST model is stiff at low speed (eigenvalues ~ -215 1/s at
1 m/s for the Ford Escort): RK4 at 0.1 s would be unstable."""

ADAM_LEARNING_RATE = 0.01
"""The paper's Adam learning rate."""
ADAM_BATCH_SIZE = 1024
"""The paper's batch size [windows]."""

COVARIANCES = ("hac", "iid")
"""Ways to compute the standard deviations (``FitOptions.covariance``): ``hac`` (default) the
sandwich with a Newey-West estimate over time-ordered windows (honest under model error and
correlated residuals); ``iid`` the Gauss-Newton ``(J^T J / s2)^-1`` of independent residuals."""
HAC_LAG_S = 2.0
"""Time over which the scores of windows are taken as correlated in the ``hac`` covariance [s]
(beyond a window's own span: a model error persists over a manoeuvre, ~2 s of the NMPC's
horizon)."""


def with_model_error(mu: float, std: float, model_error_rel: float) -> float:
    """mu's std with the model-error budget: ``sqrt(std^2 + (model_error_rel * mu)^2)``."""
    if model_error_rel <= 0 or not math.isfinite(std):
        return std
    return math.hypot(std, model_error_rel * abs(mu))


def without_model_error(mu: float, std: float, model_error_rel: float) -> float:
    """The std the data leave, from one that carries the model-error budget (the inverse of
    :func:`with_model_error`; 0 where the budget is all of it)."""
    if model_error_rel <= 0 or not math.isfinite(std):
        return std
    return math.sqrt(max(std**2 - (model_error_rel * mu) ** 2, 0.0))


STATUS_CONVERGED = "converged"
STATUS_MAX_ITERATIONS = "max_iterations"
STATUS_DIVERGED = "diverged"
STATUS_TOO_LITTLE_DATA = "too_little_data"
STATUS_TARGET_REACHED = "target_reached"


@dataclass(frozen=True)
class FitOptions:
    """Options of a fit.

    Attributes:
        free: names of the fitted parameters, a subset of ("mu", "C_Sf", "C_Sr"); the others stay
            at their values in the starting theta.
        prior_sigma: Gaussian prior standard deviation per parameter name (mean: the vehicle's
            nominal value), e.g. ``{"C_Sf": 2.0, "C_Sr": 2.0}``; ``None`` = no priors.
        mu_bounds: bounds of mu.
        stiffness_rel_bounds: bounds of C_Sf, C_Sr relative to the nominal values.
        state_scales: residual scales per state (see ``DEFAULT_STATE_SCALES``).
        max_iterations: Gauss-Newton iterations (Jacobian evaluations) at most.
        ftol: stop when an accepted step lowered the objective by less than this fraction, or
            when the next Gauss-Newton step is predicted to (checked before it is evaluated).
        xtol: stop when the Gauss-Newton step changes every parameter by less than this fraction
            of its value (checked before the step is evaluated).
        coarse_windows: with at least 4x as many windows, first fit an evenly spaced subset of
            this many windows (to ``coarse_xtol``), then refine on all windows (None: off).
            Each stage runs at most ``max_iterations`` iterations.
        coarse_xtol: the step tolerance of the coarse stage.
        max_step_s: longest RK4 step of the rollouts [s] (see ``MAX_STEP_S``).
        min_windows: fewer windows than this: no fit, the starting theta is kept.
        cond_warn: condition number of the scaled information matrix above which a warning is
            raised.
        rel_std_warn: relative standard deviation above which a parameter is reported as poorly
            determined.
        covariance: ``hac`` (default) or ``iid``: how the standard deviations are computed (see
            ``COVARIANCES``).
        hac_lag_s: the ``hac`` covariance's correlation time beyond a window's span [s].
        model_error_rel: a model-error budget: mu's std is ``sqrt(std^2 + (model_error_rel *
            mu)^2)`` (0: none). For an error every window shares (a biased tyre law), which no
            covariance of the context's own data sees; calibrated against ground truth
            (``pcvfe evaluate --report DIR --interval-coverage --calibrate``, docs/fitting.md).
    """

    free: tuple[str, ...] = ("mu",)
    prior_sigma: Mapping[str, float] | None = None
    mu_bounds: tuple[float, float] = MU_BOUNDS
    stiffness_rel_bounds: tuple[float, float] = STIFFNESS_REL_BOUNDS
    state_scales: tuple[float, ...] = DEFAULT_STATE_SCALES
    max_iterations: int = 30
    ftol: float = 1e-9
    xtol: float = 1e-7
    coarse_windows: int | None = 64
    coarse_xtol: float = 1e-3
    max_step_s: float = MAX_STEP_S
    min_windows: int = 20
    cond_warn: float = 1e8
    rel_std_warn: float = 0.5
    covariance: str = "hac"
    hac_lag_s: float = HAC_LAG_S
    model_error_rel: float = 0.0

    def __post_init__(self) -> None:
        free = tuple(self.free)
        object.__setattr__(self, "free", free)
        if not free or any(name not in THETA_NAMES for name in free) or len(set(free)) != len(free):
            raise ValueError(f"free must be distinct names from {THETA_NAMES}, got {free!r}")
        for name, sigma in (self.prior_sigma or {}).items():
            if name not in THETA_NAMES:
                raise ValueError(f"prior_sigma: unknown parameter {name!r} (use {THETA_NAMES})")
            if not (math.isfinite(sigma) and sigma > 0):
                raise ValueError(f"prior_sigma[{name!r}] must be > 0, got {sigma!r}")
        lo, hi = self.mu_bounds
        if not 0 < lo < hi:
            raise ValueError(f"mu_bounds must satisfy 0 < low < high, got {self.mu_bounds!r}")
        lo, hi = self.stiffness_rel_bounds
        if not 0 < lo < 1 < hi:
            raise ValueError(
                f"stiffness_rel_bounds must satisfy 0 < low < 1 < high, got "
                f"{self.stiffness_rel_bounds!r}"
            )
        scales = np.asarray(self.state_scales, dtype=float)
        if scales.shape != (7,) or not np.all(np.isfinite(scales) & (scales > 0)):
            raise ValueError(f"state_scales must be 7 positive numbers, got {self.state_scales!r}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations!r}")
        if not (math.isfinite(self.max_step_s) and self.max_step_s > 0):
            raise ValueError(f"max_step_s must be > 0 s, got {self.max_step_s!r}")
        if self.min_windows < 1:
            raise ValueError(f"min_windows must be >= 1, got {self.min_windows!r}")
        if self.covariance not in COVARIANCES:
            raise ValueError(f"covariance must be one of {COVARIANCES}, got {self.covariance!r}")
        if not (math.isfinite(self.hac_lag_s) and self.hac_lag_s >= 0):
            raise ValueError(f"hac_lag_s must be >= 0 s, got {self.hac_lag_s!r}")
        if not (math.isfinite(self.model_error_rel) and self.model_error_rel >= 0):
            raise ValueError(f"model_error_rel must be >= 0, got {self.model_error_rel!r}")

    @property
    def free_index(self) -> np.ndarray:
        return np.array([THETA_NAMES.index(name) for name in self.free])

    @property
    def weights(self) -> np.ndarray:
        """1 / state_scales, (7,)."""
        return 1.0 / np.asarray(self.state_scales, dtype=float)

    def bounds(self, params: VehicleParams) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of [mu, C_Sf, C_Sr] for ``params``."""
        lo_rel, hi_rel = self.stiffness_rel_bounds
        lower = np.array([self.mu_bounds[0], lo_rel * params.C_Sf, lo_rel * params.C_Sr])
        upper = np.array([self.mu_bounds[1], hi_rel * params.C_Sf, hi_rel * params.C_Sr])
        return lower, upper

    def prior(self, params: VehicleParams) -> tuple[np.ndarray, np.ndarray]:
        """Prior mean (the nominal theta) and precision 1/sigma^2 (0 = no prior), each (3,)."""
        precision = np.zeros(NTHETA)
        for name, sigma in (self.prior_sigma or {}).items():
            precision[THETA_NAMES.index(name)] = 1.0 / sigma**2
        return params.theta, precision


JOINT_PRIOR_REL_SIGMA = 0.1
"""Default prior standard deviation of C_Sf, C_Sr in joint fits, relative to the nominal values."""


def joint_options(params: VehicleParams, rel_sigma: float | None = JOINT_PRIOR_REL_SIGMA, **kw):
    """Options fitting mu, C_Sf and C_Sr, with Gaussian priors on the stiffnesses.

    ``rel_sigma``: prior standard deviation relative to the nominal stiffness; ``None`` = no priors
    (the fit is then ill-posed in the ST model and says so).
    """
    prior = None
    if rel_sigma is not None:
        prior = {"C_Sf": rel_sigma * params.C_Sf, "C_Sr": rel_sigma * params.C_Sr}
    return FitOptions(free=THETA_NAMES, prior_sigma=prior, **kw)


@dataclass
class FitResult:
    """The outcome of fitting one context.

    Attributes:
        theta: [mu, C_Sf, C_Sr] estimate (the starting value if nothing was fitted).
        std: standard deviations of theta (NaN for parameters not fitted; inf if the data carry
            no information on a parameter).
        loss: final mean weighted squared error per window step (see module docstring).
        loss_initial: the same at the starting theta.
        n_windows: windows used.
        windows_skipped: reason -> skipped candidate windows attributed to this context (see
            ``fit_dataset.SKIP_REASONS``); filled by :func:`fit_contexts`, zeros when a solver is
            called on a dataset directly.
        converged: the solver met its convergence test (or the target loss).
        status: one of "converged", "target_reached", "max_iterations", "diverged",
            "too_little_data".
        iterations: solver iterations (Gauss-Newton: Jacobian evaluations; Adam: steps).
        warnings: human-readable warnings (identifiability, conditioning, data).
        free: the fitted parameter names.
        solver: "gauss_newton" or "adam".
        condition_number: of the parameter-scaled information matrix of the free parameters.
        ill_conditioned: the condition number exceeds ``FitOptions.cond_warn``.
        elapsed_s: wall time of the fit [s].
        residual_rms: RMS of the *unweighted* residuals per state at the end (state units).
        rollouts: rollouts with sensitivities the solver ran, in full-dataset equivalents (a
            measure of work independent of the machine).
        quality: the checks of ``fit_quality.assess`` (parameters at a bound, loss against the
            noise, fit percent, influential windows); empty when nothing was fitted.
    """

    theta: np.ndarray
    std: np.ndarray
    loss: float
    loss_initial: float
    n_windows: int
    windows_skipped: dict[str, int]
    converged: bool
    status: str
    iterations: int
    warnings: list[str] = field(default_factory=list)
    free: tuple[str, ...] = ("mu",)
    solver: str = "gauss_newton"
    condition_number: float = float("nan")
    ill_conditioned: bool = False
    elapsed_s: float = 0.0
    residual_rms: np.ndarray = field(default_factory=lambda: np.full(7, np.nan))
    rollouts: float = 0.0
    quality: dict = field(default_factory=dict)

    @property
    def mu(self) -> float:
        return float(self.theta[0])

    def to_dict(self) -> dict:
        """A JSON-ready dict (NaN/inf become None)."""

        return {
            "theta": {n: finite_or_none(v) for n, v in zip(THETA_NAMES, self.theta, strict=True)},
            "std": {n: finite_or_none(v) for n, v in zip(THETA_NAMES, self.std, strict=True)},
            "free": list(self.free),
            "loss": finite_or_none(self.loss),
            "loss_initial": finite_or_none(self.loss_initial),
            "n_windows": int(self.n_windows),
            "windows_skipped": {k: int(v) for k, v in self.windows_skipped.items()},
            "converged": bool(self.converged),
            "status": self.status,
            "iterations": int(self.iterations),
            "solver": self.solver,
            "condition_number": finite_or_none(self.condition_number),
            "ill_conditioned": bool(self.ill_conditioned),
            "warnings": list(self.warnings),
            "elapsed_s": finite_or_none(self.elapsed_s),
            "quality": _jsonable(self.quality),
        }


def _jsonable(obj):
    """Nested dicts/lists with non-finite floats as None."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj
