"""Context-specific friction fitting through the ST dynamics (paper eq. 5a-5d).

Loss
----
For a window (``pcvfe_drake.estimation.fit_dataset``) the ST model is rolled out from the measured
initial
state (5b) with the recorded inputs (5c, RK4 at the log step) and compared with the measured
states at steps 1..H. The residual of state j at step k is

    r_kj = (x_hat_kj - x_kj) / s_j                  for every state but the heading,
    r_k,psi = wrap(psi_hat_k - psi_k) / s_psi        (wrapped to (-pi, pi]),

with per-state scales ``s`` (``DEFAULT_STATE_SCALES``: the expected measurement noise standard
deviations, so that each residual is in units of its noise and the squared sum is a negative
log-likelihood under independent Gaussian noise). The loss is

    loss(theta) = (1 / (B H)) * sum over windows, steps and states of r^2,

the mean weighted squared error per window step. Differences from eq. 5a: the paper adds the
*absolute* wrapped heading error ``|atan2(sin e, cos e)|`` to an unweighted squared error of the
other states. The absolute value is not differentiable at zero, which Gauss-Newton needs; here the
wrapped heading error is squared like the others, and the states are weighted by their scales
(positions in m, angles in rad and rates in rad/s differ by orders of magnitude).

Solvers
-------
* :func:`fit_gauss_newton` (default): a bounded Levenberg-Marquardt (Gauss-Newton with
  Marquardt damping and projection onto the bounds, an active set at the bounds) using the exact
  rollout sensitivities ``dX/dtheta`` of ``pcvfe_drake.vehicle.single_track.rollout``; warm-started
  from the
  given theta (e.g. the previous estimate).
* :func:`fit_adam`: the paper's optimiser: Adam, learning rate 0.01, batch 1024, gradients through
  the rollout (exact, from the same sensitivities), projected onto the bounds.

Identifiability
---------------
In the ST model mu enters only as ``mu * C_Sf`` and ``mu * C_Sr``. By default only mu is fitted
and the stiffnesses stay at the vehicle's nominal values. Joint fits take Gaussian priors
(``FitOptions.prior_sigma``, mean = the vehicle's nominal values). Every result reports standard
deviations from the Gauss-Newton information matrix ``J^T J / s2 + Lambda_prior`` (``s2`` the
residual variance estimate ``SSR / (n - p)``; ``Lambda_prior`` the prior precision) and a warning
when the (parameter-scaled) information matrix is ill-conditioned. These standard deviations treat
the residuals as independent; overlapping windows and correlated model errors make them
optimistic.
"""

from __future__ import annotations

import math
import time
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.estimation.fit_dataset import SKIP_REASONS, WindowDataset, WindowSplit
from pcvfe_drake.vehicle.params import THETA_NAMES, VehicleParams
from pcvfe_drake.vehicle.single_track import NTHETA, PSI, rollout, wrap_angle

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

    @property
    def mu(self) -> float:
        return float(self.theta[0])

    def to_dict(self) -> dict:
        """A JSON-ready dict (NaN/inf become None)."""

        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {
            "theta": {n: num(v) for n, v in zip(THETA_NAMES, self.theta, strict=True)},
            "std": {n: num(v) for n, v in zip(THETA_NAMES, self.std, strict=True)},
            "free": list(self.free),
            "loss": num(self.loss),
            "loss_initial": num(self.loss_initial),
            "n_windows": int(self.n_windows),
            "windows_skipped": {k: int(v) for k, v in self.windows_skipped.items()},
            "converged": bool(self.converged),
            "status": self.status,
            "iterations": int(self.iterations),
            "solver": self.solver,
            "condition_number": num(self.condition_number),
            "ill_conditioned": bool(self.ill_conditioned),
            "warnings": list(self.warnings),
            "elapsed_s": num(self.elapsed_s),
        }


# --------------------------------------------------------------------------------------------
# Loss and its derivatives


def _check_theta(theta, params: VehicleParams) -> np.ndarray:
    theta = params.theta if theta is None else np.asarray(theta, dtype=float).reshape(-1)
    if theta.shape != (NTHETA,) or not np.all(np.isfinite(theta)):
        raise ValueError(f"theta must be 3 finite numbers [mu, C_Sf, C_Sr], got {theta!r}")
    return theta.astype(float)


def window_residuals(
    theta,
    data: WindowDataset,
    params: VehicleParams,
    weights=None,
    jacobian: bool = False,
    max_step_s: float = MAX_STEP_S,
):
    """Weighted residuals of the rollouts, and optionally their derivative w.r.t. theta.

    Returns ``R`` (B, H, 7) (see the module docstring), and with ``jacobian=True`` also
    ``J = dR/dtheta`` (B, H, 7, 3) from the exact rollout sensitivities. Rollouts that leave the
    finite range give non-finite residuals instead of raising. A data step longer than
    ``max_step_s`` is integrated in equal RK4 substeps (inputs held over the data step).
    """
    theta = _check_theta(theta, params)
    if weights is None:
        w = 1.0 / np.asarray(DEFAULT_STATE_SCALES, dtype=float)
    else:
        w = np.asarray(weights, dtype=float)
    substeps = max(1, math.ceil(data.dt / max_step_s - 1e-9))
    U = np.repeat(data.U, substeps, axis=1) if substeps > 1 else data.U
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            out = rollout(
                data.x0, U, params, data.dt / substeps, theta=theta, sensitivities=jacobian
            )
    except ValueError:
        # rk4_step refuses non-finite intermediate states: the rollout diverged at this theta.
        R = np.full(data.X.shape, np.nan)
        return (R, np.full((*data.X.shape, NTHETA), np.nan)) if jacobian else R
    X, S = out if jacobian else (out, None)
    if substeps > 1:
        X = X[:, ::substeps]
        S = None if S is None else S[:, ::substeps]
    E = X[:, 1:] - data.X
    E[..., PSI] = wrap_angle(E[..., PSI])
    R = E * w
    if not jacobian:
        return R
    return R, S[:, 1:] * w[:, None]


def window_loss(
    theta, data: WindowDataset, params: VehicleParams, weights=None, max_step_s: float = MAX_STEP_S
) -> float:
    """The loss (mean weighted squared error per window step) at ``theta``."""
    R = window_residuals(theta, data, params, weights, max_step_s=max_step_s)
    return float(np.sum(R * R) / max(data.n_windows * data.horizon, 1))


def window_loss_and_gradient(
    theta, data: WindowDataset, params: VehicleParams, weights=None, max_step_s: float = MAX_STEP_S
) -> tuple[float, np.ndarray]:
    """The loss and its exact gradient w.r.t. [mu, C_Sf, C_Sr] (through the rollout)."""
    R, J = window_residuals(theta, data, params, weights, jacobian=True, max_step_s=max_step_s)
    count = max(data.n_windows * data.horizon, 1)
    loss = float(np.sum(R * R) / count)
    grad = 2.0 * np.einsum("bhs,bhsp->p", R, J) / count
    return loss, grad


# --------------------------------------------------------------------------------------------
# Uncertainty and identifiability


def _uncertainty(
    theta: np.ndarray,
    R: np.ndarray,
    J: np.ndarray,
    options: FitOptions,
    params: VehicleParams,
) -> tuple[np.ndarray, float, bool, list[str]]:
    """Standard deviations, condition number, ill-conditioned flag and warnings at ``theta``."""
    free = options.free_index
    p = free.size
    r = R.reshape(-1)
    Jf = J.reshape(-1, NTHETA)[:, free]
    n = r.size
    std = np.full(NTHETA, np.nan)
    warnings: list[str] = []
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(Jf))):
        return std, float("nan"), True, ["non-finite residuals at the estimate"]
    _, precision = options.prior(params)
    prior_prec = precision[free]
    info = _gram(Jf)
    ssr = float(r @ r)
    s2 = ssr / max(n - p, 1)
    # Conditioning of the information in parameter-relative units (independent of s2).
    scale = np.abs(theta[free])
    scaled = scale[:, None] * (info + np.diag(prior_prec)) * scale[None, :]
    eig = np.linalg.eigvalsh(scaled)
    if eig[-1] <= 0:
        cond = float("inf")
    else:
        cond = float(eig[-1] / eig[0]) if eig[0] > eig[-1] * 1e-300 else float("inf")
    ill = not (cond <= options.cond_warn)
    names = [THETA_NAMES[i] for i in free]
    if eig[-1] <= 1e-12 * max(n, 1):
        warnings.append(
            f"the data carry no information on {', '.join(names)}: no lateral excitation "
            "(steering, yaw rate, side slip) in the windows"
        )
        std[free] = np.inf
        return std, cond, True, warnings
    if ill:
        no_prior = [nm for nm, pp in zip(names, prior_prec, strict=True) if pp == 0]
        warnings.append(
            f"ill-conditioned information matrix (condition number {cond:.3g}): the data do not "
            f"separate {', '.join(names)}; in the ST model mu enters only as mu*C_Sf and mu*C_Sr. "
            + (
                f"Fit mu alone or add priors on {', '.join(nm for nm in no_prior if nm != 'mu')}."
                if len(no_prior) > 1
                else "Use stronger priors or more varied excitation."
            )
        )
    posterior = info / max(s2, 1e-300) + np.diag(prior_prec)
    try:
        cov = np.linalg.inv(posterior)
        diag = np.diag(cov)
        std[free] = np.sqrt(np.where(diag >= 0, diag, np.inf))
    except np.linalg.LinAlgError:
        std[free] = np.inf
    for i, name in zip(free, names, strict=True):
        if not (std[i] <= options.rel_std_warn * abs(theta[i])):
            warnings.append(
                f"{name} is poorly determined: std {std[i]:.3g} vs estimate {theta[i]:.3g}"
            )
    if np.any(prior_prec > 0):
        data_scaled = scale[:, None] * info * scale[None, :]
        deig = np.linalg.eigvalsh(data_scaled)
        if not (deig[0] > 0 and deig[-1] / deig[0] <= options.cond_warn):
            warnings.append(
                "the data alone do not separate the fitted parameters; the priors determine the "
                "split between mu and the stiffnesses"
            )
    return std, cond, ill, warnings


def _gram(Jf: np.ndarray) -> np.ndarray:
    """``Jf^T Jf`` for a tall, thin ``Jf`` (n, p); einsum avoids the slow BLAS path of matmul for
    this shape (tens of ms for n ~ 1e5 under load, against ~0.1 ms)."""
    return np.einsum("ni,nj->ij", Jf, Jf)


def _residual_rms(R: np.ndarray, weights: np.ndarray) -> np.ndarray:
    if R.size == 0:
        return np.full(7, np.nan)
    return np.sqrt(np.mean((R / weights) ** 2, axis=(0, 1)))


def _no_fit_result(
    theta0: np.ndarray, data: WindowDataset | None, options: FitOptions, solver: str, status: str
) -> FitResult:
    n = 0 if data is None else data.n_windows
    return FitResult(
        theta=theta0.copy(),
        std=np.full(NTHETA, np.nan),
        loss=float("nan"),
        loss_initial=float("nan"),
        n_windows=n,
        windows_skipped=dict.fromkeys(SKIP_REASONS, 0),
        converged=False,
        status=status,
        iterations=0,
        warnings=[f"too little data: {n} windows < {options.min_windows}; the prior theta is kept"]
        if status == STATUS_TOO_LITTLE_DATA
        else [],
        free=options.free,
        solver=solver,
    )


def _final_result(
    theta: np.ndarray,
    R: np.ndarray,
    J: np.ndarray,
    data: WindowDataset,
    params: VehicleParams,
    options: FitOptions,
    solver: str,
    status: str,
    success_status: str,
    iterations: int,
    loss_initial: float,
    start_time: float,
    rollouts: float,
    note: str | None,
) -> FitResult:
    """The FitResult at the final theta (residuals R and Jacobian J evaluated there)."""
    std, cond, ill, warnings = _uncertainty(theta, R, J, options, params)
    loss = float(np.sum(R * R)) / (data.n_windows * data.horizon)
    if not (math.isfinite(loss) and np.all(np.isfinite(theta))):
        status = STATUS_DIVERGED
    if note:
        warnings.append(note)
    if status == STATUS_DIVERGED:
        warnings.append(f"{solver} diverged (non-finite loss); the best finite iterate is returned")
    return FitResult(
        theta=theta,
        std=std,
        loss=loss,
        loss_initial=loss_initial,
        n_windows=data.n_windows,
        windows_skipped=dict.fromkeys(SKIP_REASONS, 0),
        converged=status == success_status,
        status=status,
        iterations=iterations,
        warnings=warnings,
        free=options.free,
        solver=solver,
        condition_number=cond,
        ill_conditioned=ill,
        elapsed_s=time.perf_counter() - start_time,
        residual_rms=_residual_rms(R, options.weights),
        rollouts=rollouts,
    )


# --------------------------------------------------------------------------------------------
# Solvers


def _start(theta0, params: VehicleParams, data, options: FitOptions, solver: str):
    """The start shared by both solvers: ``(theta, lower, upper, no_fit)`` with theta0 checked
    and clipped into the bounds, and ``no_fit`` the result to return when there are too few
    windows (else None)."""
    lower, upper = options.bounds(params)
    theta = np.clip(_check_theta(theta0, params), lower, upper)
    if data is None or data.n_windows < options.min_windows:
        return (
            theta,
            lower,
            upper,
            _no_fit_result(theta, data, options, solver, STATUS_TOO_LITTLE_DATA),
        )
    return theta, lower, upper, None


def fit_gauss_newton(
    data: WindowDataset,
    params: VehicleParams,
    theta0=None,
    options: FitOptions | None = None,
) -> FitResult:
    """Bounded Levenberg-Marquardt fit of the free parameters with exact rollout sensitivities.

    Args:
        data: the windows of one context.
        params: the vehicle (nominal theta = prior mean and the default start).
        theta0: starting [mu, C_Sf, C_Sr] (warm start, e.g. the previous estimate); clipped into
            the bounds. Default: the vehicle's nominal values.
        options: see :class:`FitOptions`.
    """
    options = FitOptions() if options is None else options
    start_time = time.perf_counter()
    theta, lower, upper, no_fit = _start(theta0, params, data, options, "gauss_newton")
    if no_fit is not None:
        return no_fit
    free = options.free_index
    weights = options.weights
    prior_mean, precision = options.prior(params)
    count = data.n_windows * data.horizon

    def prior_ss(th):
        return float(np.sum(precision * (th - prior_mean) ** 2))

    work = [0.0]  # rollouts with sensitivities, in full-dataset equivalents

    def objective(th, windows):
        # Trial points are evaluated with sensitivities: most steps are accepted, and then the
        # next iteration needs them (one rollout per iteration instead of two).
        R_t, J_t = window_residuals(th, windows, params, weights, True, options.max_step_s)
        work[0] += windows.n_windows / data.n_windows
        with np.errstate(over="ignore", invalid="ignore"):
            value = float(np.sum(R_t * R_t)) + prior_ss(th)
        return (value if math.isfinite(value) else float("inf")), R_t, J_t

    def diverged_result():
        result = _no_fit_result(theta, data, options, "gauss_newton", STATUS_DIVERGED)
        result.warnings.append("the rollout loss is not finite at the starting theta")
        result.elapsed_s = time.perf_counter() - start_time
        return result

    def levenberg_marquardt(theta, cost, R, J, windows, max_iterations, xtol, ftol):
        """Bounded LM from theta (cost, R, J evaluated there); returns the final state."""
        lam = 1e-3
        status = STATUS_MAX_ITERATIONS
        iterations = 0
        scale = np.maximum(np.abs(theta[free]), 1e-6)  # work in parameter-relative units
        while iterations < max_iterations:
            iterations += 1
            Jf = J.reshape(-1, NTHETA)[:, free] * scale
            r = R.reshape(-1)
            grad = np.einsum("ni,n->i", Jf, r) + scale * precision[free] * (
                theta[free] - prior_mean[free]
            )
            hess = _gram(Jf) + np.diag(scale**2 * precision[free])
            # Active set: parameters at a bound whose descent direction leaves the box stay.
            at_lo = (theta[free] <= lower[free]) & (grad > 0)
            at_hi = (theta[free] >= upper[free]) & (grad < 0)
            inactive = ~(at_lo | at_hi)
            if not inactive.any() or np.max(np.abs(grad[inactive])) <= 1e-14 * max(cost, 1e-300):
                status = STATUS_CONVERGED
                break
            accepted = False
            while lam <= 1e12:
                h = hess[np.ix_(inactive, inactive)]
                floor = 1e-12 * np.trace(hess) + 1e-300
                damped = h + lam * np.diag(np.maximum(np.diag(h), floor))
                step = np.zeros(free.size)
                try:
                    step[inactive] = np.linalg.solve(damped, -grad[inactive])
                except np.linalg.LinAlgError:
                    lam *= 10.0
                    continue
                trial = theta.copy()
                trial[free] = np.clip(theta[free] + step * scale, lower[free], upper[free])
                taken = (trial[free] - theta[free]) / scale
                rel_step = np.max(np.abs(taken))
                predicted = -(grad @ taken + 0.5 * taken @ hess @ taken)
                if lam <= 1e-2 and (rel_step <= xtol or predicted <= ftol * cost):
                    # The (nearly undamped) Gauss-Newton step is negligible, or would lower the
                    # objective by less than ftol: converged here, without another rollout.
                    return theta, cost, R, J, STATUS_CONVERGED, iterations
                trial_cost, trial_R, trial_J = objective(trial, windows)
                if trial_cost < cost:
                    accepted = True
                    break
                lam *= 10.0
            if not accepted:
                status = STATUS_CONVERGED  # no descent direction left at machine precision
                break
            decrease = (cost - trial_cost) / max(cost, 1e-300)
            theta, cost, R, J = trial, trial_cost, trial_R, trial_J
            lam = max(lam / 10.0, 1e-9)
            if decrease <= ftol:
                status = STATUS_CONVERGED
                break
        return theta, cost, R, J, status, iterations

    def full_start(th):
        """Objective, residuals and Jacobian on all windows, and the loss, at th."""
        value, R_s, J_s = objective(th, data)
        return value, R_s, J_s, (value - prior_ss(th)) / count

    iterations = 0
    coarse = options.coarse_windows
    theta_c = theta
    if coarse and data.n_windows >= 4 * coarse:
        # Coarse stage: an evenly spaced subset brings theta close at a fraction of the cost
        # (from a warm start it usually takes no step at all).
        pick = np.linspace(0, data.n_windows - 1, coarse).round().astype(int)
        subset = data.subset(pick)
        sub_cost, sub_R, sub_J = objective(theta, subset)
        if math.isfinite(sub_cost) and np.all(np.isfinite(sub_J)):
            theta_c, _, _, _, _, iterations = levenberg_marquardt(
                theta,
                sub_cost,
                sub_R,
                sub_J,
                subset,
                options.max_iterations,
                options.coarse_xtol,
                options.coarse_xtol**2,
            )
    if theta_c is not theta and not np.array_equal(theta_c, theta):
        # The coarse stage moved: the start's loss without sensitivities, then all windows at
        # the coarse result (kept if it is better on all windows, as it nearly always is).
        R0 = window_residuals(theta, data, params, weights, max_step_s=options.max_step_s)
        with np.errstate(over="ignore", invalid="ignore"):
            cost0 = float(np.sum(R0 * R0)) + prior_ss(theta)
        loss_initial = (cost0 - prior_ss(theta)) / count
        cost, R, J, _ = full_start(theta_c)
        if cost < cost0 and np.all(np.isfinite(J)):
            theta = theta_c
        else:
            cost, R, J, _ = full_start(theta)
    else:
        cost, R, J, loss_initial = full_start(theta)
    if not math.isfinite(cost) or not np.all(np.isfinite(J)):
        return diverged_result()
    theta, cost, R, J, status, fine_iterations = levenberg_marquardt(
        theta,
        cost,
        R,
        J,
        data,
        options.max_iterations,
        options.xtol,
        options.ftol,
    )
    iterations += fine_iterations

    if status == STATUS_MAX_ITERATIONS:
        note = f"stopped after {iterations} iterations before convergence"
    else:
        note = None
    return _final_result(
        theta,
        R,
        J,
        data,
        params,
        options,
        "gauss_newton",
        status,
        STATUS_CONVERGED,
        iterations,
        loss_initial,
        start_time,
        work[0],
        note,
    )


def fit_adam(
    data: WindowDataset,
    params: VehicleParams,
    theta0=None,
    options: FitOptions | None = None,
    *,
    learning_rate: float = ADAM_LEARNING_RATE,
    batch_size: int = ADAM_BATCH_SIZE,
    max_steps: int = 2000,
    target_loss: float | None = None,
    check_every: int = 10,
    seed: int = 0,
    betas: tuple[float, float] = (0.9, 0.999),
    eps: float = 1e-8,
    history: list | None = None,
) -> FitResult:
    """The paper's solver: Adam on the loss, gradients through the rollout, projected on bounds.

    Each step draws a batch of ``batch_size`` windows (all windows when there are fewer) and
    follows the exact gradient of that batch's loss (plus the priors, per window step).

    Args:
        target_loss: stop once the loss over all windows is at or below this (checked every step
            when a batch holds all windows, else every ``check_every`` steps).
        max_steps: step cap. Other arguments: the optimiser's hyper-parameters (PyTorch's
            defaults for betas and eps), the random seed of the batch draw.
        history: if given, ``(step, wall_s, cpu_s, full_loss, theta)`` (times since the start)
            is appended at every full-data loss evaluation (for benchmarks).
    Returns:
        a :class:`FitResult` with the best theta seen on full-data loss checks (the last iterate
        when the batch is the whole dataset).
    """
    options = FitOptions() if options is None else options
    if not (learning_rate > 0 and batch_size >= 1 and max_steps >= 1 and check_every >= 1):
        raise ValueError(
            f"fit_adam: need learning_rate > 0, batch_size >= 1, max_steps >= 1, check_every >= 1"
            f" (got {learning_rate!r}, {batch_size!r}, {max_steps!r}, {check_every!r})"
        )
    start_time = time.perf_counter()
    start_cpu = time.process_time()

    def elapsed():
        return time.perf_counter() - start_time, time.process_time() - start_cpu

    theta, lower, upper, no_fit = _start(theta0, params, data, options, "adam")
    if no_fit is not None:
        return no_fit
    free = options.free_index
    weights = options.weights
    prior_mean, precision = options.prior(params)
    rng = np.random.default_rng(seed)
    n = data.n_windows
    full_batch = n <= batch_size
    beta1, beta2 = betas
    m = np.zeros(free.size)
    v = np.zeros(free.size)
    best_theta, best_loss = theta.copy(), float("inf")
    loss_initial = float("nan")
    status = STATUS_MAX_ITERATIONS
    steps = 0
    work = 0.0
    for step in range(1, max_steps + 1):
        batch = data if full_batch else data.subset(rng.choice(n, batch_size, replace=False))
        loss_b, grad = window_loss_and_gradient(theta, batch, params, weights, options.max_step_s)
        work += batch.n_windows / n
        count = batch.n_windows * batch.horizon
        full = None
        if full_batch:
            full = loss_b
        elif step == 1 or step % check_every == 0:
            full = window_loss(theta, data, params, weights, options.max_step_s)
        if full is not None:
            if step == 1:
                loss_initial = full
            if not math.isfinite(full):
                status = STATUS_DIVERGED
                break
            if history is not None:
                history.append((step, *elapsed(), full, theta.copy()))
            if full < best_loss:
                best_theta, best_loss = theta.copy(), full
            if target_loss is not None and full <= target_loss:
                status = STATUS_TARGET_REACHED
                break
        g = grad[free] + 2.0 * precision[free] * (theta[free] - prior_mean[free]) / count
        if not np.all(np.isfinite(g)):
            status = STATUS_DIVERGED
            break
        steps = step
        m = beta1 * m + (1.0 - beta1) * g
        v = beta2 * v + (1.0 - beta2) * g * g
        m_hat = m / (1.0 - beta1**step)
        v_hat = v / (1.0 - beta2**step)
        theta = theta.copy()
        theta[free] = np.clip(
            theta[free] - learning_rate * m_hat / (np.sqrt(v_hat) + eps), lower[free], upper[free]
        )
    if status == STATUS_MAX_ITERATIONS:
        final = window_loss(theta, data, params, weights, options.max_step_s)
        if final < best_loss:
            best_theta, best_loss = theta.copy(), final
    theta = best_theta
    R, J = window_residuals(theta, data, params, weights, True, options.max_step_s)
    return _final_result(
        theta,
        R,
        J,
        data,
        params,
        options,
        "adam",
        status,
        STATUS_TARGET_REACHED,
        steps,
        loss_initial,
        start_time,
        work,
        None,
    )


SOLVERS = {"gauss_newton": fit_gauss_newton, "adam": fit_adam}


def fit_contexts(
    split: WindowSplit,
    params: VehicleParams,
    options: FitOptions | None = None,
    *,
    theta0: Mapping[Hashable, np.ndarray] | None = None,
    solver: str = "gauss_newton",
) -> dict[Hashable, FitResult]:
    """Fit every context of a :class:`WindowSplit` (e.g. from ``windows_from_log``).

    Contexts with fewer than ``options.min_windows`` windows (including contexts seen in the
    samples but without any usable window) get the starting theta with status
    "too_little_data". ``theta0`` maps labels to warm starts (default: the nominal theta).
    """
    options = FitOptions() if options is None else options
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {sorted(SOLVERS)}, got {solver!r}")
    results: dict[Hashable, FitResult] = {}
    labels = list(dict.fromkeys([*split.samples, *split.by_context]))
    for label in labels:
        start = None if theta0 is None else theta0.get(label)
        data = split.by_context.get(label)
        result = SOLVERS[solver](data, params, start, options)
        result.windows_skipped = dict(
            split.skipped_by_context.get(label, dict.fromkeys(SKIP_REASONS, 0))
        )
        results[label] = result
    return results
