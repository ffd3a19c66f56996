"""One bounded nonlinear least-squares core (Levenberg-Marquardt with an active set).

Used by the context fitter (``pcvfe_drake.estimation.fitting.fit_gauss_newton``: exact rollout
sensitivities) and by the workbench (``pcvfe_drake.models.estimate.fit``: finite-difference
sensitivities in one batched rollout), so that diagnosis and estimation minimise the same kind of
objective with the same algorithm::

    cost(theta) = || r(theta) ||^2 + sum_i precision_i (theta_i - prior_mean_i)^2

over ``lower <= theta <= upper``, for the parameters marked free (the others stay where they
start). The algorithm:

* steps in scaled units ``theta = theta_k + scale * s`` (``scale`` per parameter: a typical
  magnitude, so that the damping and the tolerances mean the same for every parameter);
* Marquardt damping ``(H + lam diag(H)) s = -g`` with ``H = J^T J + prior``, projected onto the
  bounds (the trial point is clipped into the box);
* an active set: a parameter on a bound whose gradient points out of the box is held there for
  the step;
* a trial point is accepted when it lowers the cost (then ``lam /= lam_down``), else ``lam *=
  lam_up`` and the step is recomputed (at most ``max_rejections`` times per iteration);
* statuses: ``converged`` (the gradient vanishes on the free set, the nearly undamped step is
  below ``xtol`` in scaled units or predicted to lower the cost by less than ``ftol`` of it, an
  accepted step lowered it by less than ``ftol``, or no step lowers it any more),
  ``max_iterations`` (the iteration cap; continue from ``theta`` with a warm start) and
  ``diverged`` (the cost is not finite at the start).

The residual function is the caller's: ``fun(theta, need_jacobian) -> (r (m,), J (m, p) or
None)``. With ``jacobian_at_trials`` the trial points are evaluated with their Jacobian (cheap
when sensitivities come with the rollout: an accepted step then reuses them); without it, only
the residuals (finite differences cost 2p + 1 rollouts), and the Jacobian is computed once a step
is accepted.

:func:`covariance` turns the Jacobian at the solution into parameter covariances (Gauss-Newton
information ``J^T J / s2`` plus the prior precision, optionally inflated for correlated residuals).
``scipy.optimize.least_squares`` (trust-region reflective) was measured against this loop on the
fitter's problem (``benchmarks/fit_speed.py``): see docs/fitting.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

STATUS_CONVERGED = "converged"
STATUS_MAX_ITERATIONS = "max_iterations"
STATUS_DIVERGED = "diverged"

ResidualFunction = Callable[[np.ndarray, bool], tuple[np.ndarray, np.ndarray | None]]
"""``fun(theta, need_jacobian) -> (r (m,), J (m, p) or None)``; non-finite r means "infeasible"."""


@dataclass
class LsqSettings:
    """Settings of :func:`solve`.

    Attributes:
        max_iterations: iterations (accepted steps or convergence checks) at most.
        xtol: converged when the nearly undamped step changes every free parameter by less than
            this, in units of its ``scale``.
        ftol: converged when the step is predicted to lower the cost by less than this fraction
            of it, or an accepted step lowered it by less than this fraction.
        lam0: initial Marquardt damping.
        lam_up, lam_down: damping factors after a rejected / an accepted step.
        max_rejections: rejected trial steps per iteration before giving up (converged).
        jacobian_at_trials: evaluate trial points with their Jacobian (see module docstring).
        predicted_check: stop on the predicted decrease / step size before evaluating a trial
            point whose damping is at most 1e-2 (saves one evaluation at convergence).
    """

    max_iterations: int = 30
    xtol: float = 1e-7
    ftol: float = 1e-9
    lam0: float = 1e-3
    lam_up: float = 10.0
    lam_down: float = 10.0
    max_rejections: int = 16
    jacobian_at_trials: bool = True
    predicted_check: bool = True

    def __post_init__(self) -> None:
        if not (isinstance(self.max_iterations, int | np.integer) and self.max_iterations >= 1):
            raise ValueError(f"LsqSettings.max_iterations must be >= 1, got {self.max_iterations}")
        for name in ("xtol", "ftol", "lam0", "lam_up", "lam_down"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"LsqSettings.{name} must be a positive number, got {value!r}")


@dataclass
class LsqResult:
    """The outcome of :func:`solve`.

    Attributes:
        theta: the final parameters (all of them; fixed ones unchanged).
        cost: the objective at theta (residuals plus prior).
        r, J: residuals and Jacobian at theta (J None when not available).
        status: ``converged``, ``max_iterations`` or ``diverged``.
        iterations: iterations taken.
        evaluations: residual evaluations (with or without Jacobian), the start included.
        jacobians: evaluations that included a Jacobian.
        history: the cost after each accepted step (the start first).
        active: per parameter, whether it ended on a bound with the gradient pushing outward.
    """

    theta: np.ndarray
    cost: float
    r: np.ndarray
    J: np.ndarray | None
    status: str
    iterations: int
    evaluations: int
    jacobians: int
    history: list[float] = field(default_factory=list)
    active: np.ndarray | None = None

    @property
    def converged(self) -> bool:
        return self.status == STATUS_CONVERGED


def _gram(J: np.ndarray) -> np.ndarray:
    """``J^T J`` for a tall, thin J; einsum avoids matmul's slow BLAS path for this shape."""
    return np.einsum("ni,nj->ij", J, J)


def solve(
    fun: ResidualFunction,
    theta0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    scale: np.ndarray,
    *,
    free: np.ndarray | None = None,
    prior_mean: np.ndarray | None = None,
    prior_precision: np.ndarray | None = None,
    settings: LsqSettings | None = None,
    start: tuple[np.ndarray, np.ndarray] | None = None,
) -> LsqResult:
    """Minimise ``||r(theta)||^2 + prior`` within ``[lower, upper]`` (see the module docstring).

    Args:
        fun: the residual function.
        theta0: start (clipped into the bounds).
        lower, upper: bounds per parameter (may be +-inf).
        scale: typical magnitude per parameter (> 0), the unit of steps and of ``xtol``.
        free: indices (or a boolean mask) of the fitted parameters (default: all).
        prior_mean, prior_precision: a Gaussian prior per parameter (precision 0: none).
        settings: see :class:`LsqSettings`.
        start: ``(r, J)`` already evaluated at ``theta0`` (saves one evaluation).
    """
    settings = LsqSettings() if settings is None else settings
    theta = np.clip(np.asarray(theta0, dtype=float).copy(), lower, upper)
    p_all = theta.size
    free_idx = np.arange(p_all) if free is None else np.asarray(free)
    if free_idx.dtype == bool:
        free_idx = np.flatnonzero(free_idx)
    mean = np.zeros(p_all) if prior_mean is None else np.asarray(prior_mean, dtype=float)
    prec = np.zeros(p_all) if prior_precision is None else np.asarray(prior_precision, dtype=float)
    lo, hi = np.asarray(lower, dtype=float)[free_idx], np.asarray(upper, dtype=float)[free_idx]
    sc = np.asarray(scale, dtype=float)[free_idx]
    if np.any(~(sc > 0)):
        raise ValueError(f"least squares: every scale must be > 0, got {sc}")
    pm, pp = mean[free_idx], prec[free_idx]
    counts = {"evaluations": 0, "jacobians": 0}

    def evaluate(th, need_jacobian):
        r, J = fun(th, need_jacobian)
        counts["evaluations"] += 1
        counts["jacobians"] += int(J is not None)
        with np.errstate(over="ignore", invalid="ignore"):
            value = float(r @ r) + float(np.sum(pp * (th[free_idx] - pm) ** 2))
        return (value if math.isfinite(value) else math.inf), r, J

    if start is not None:
        r, J = start
        with np.errstate(over="ignore", invalid="ignore"):
            cost = float(r @ r) + float(np.sum(pp * (theta[free_idx] - pm) ** 2))
        cost = cost if math.isfinite(cost) else math.inf
    else:
        cost, r, J = evaluate(theta, True)
    history = [cost]
    if not math.isfinite(cost) or J is None or not np.all(np.isfinite(J)):
        return LsqResult(theta, cost, r, J, STATUS_DIVERGED, 0, **counts, history=history)

    lam = settings.lam0
    status = STATUS_MAX_ITERATIONS
    iterations = 0
    active = np.zeros(free_idx.size, bool)
    while iterations < settings.max_iterations:
        iterations += 1
        Jf = J[:, free_idx] * sc
        grad = np.einsum("ni,n->i", Jf, r) + sc * pp * (theta[free_idx] - pm)
        hess = _gram(Jf) + np.diag(sc**2 * pp)
        x = theta[free_idx]
        active = ((x <= lo) & (grad > 0)) | ((x >= hi) & (grad < 0))
        inactive = ~active
        if not inactive.any() or np.max(np.abs(grad[inactive])) <= 1e-14 * max(cost, 1e-300):
            status = STATUS_CONVERGED
            break
        accepted = False
        h = hess[np.ix_(inactive, inactive)]
        floor = 1e-12 * np.trace(hess) + 1e-300
        marquardt = np.diag(np.maximum(np.diag(h), floor))
        for _ in range(settings.max_rejections):
            step = np.zeros(free_idx.size)
            try:
                step[inactive] = np.linalg.solve(h + lam * marquardt, -grad[inactive])
            except np.linalg.LinAlgError:
                lam *= settings.lam_up
                continue
            trial = theta.copy()
            trial[free_idx] = np.clip(x + step * sc, lo, hi)
            taken = (trial[free_idx] - x) / sc
            predicted = -(grad @ taken + 0.5 * taken @ hess @ taken)
            if (
                settings.predicted_check
                and lam <= 1e-2
                and (np.max(np.abs(taken)) <= settings.xtol or predicted <= settings.ftol * cost)
            ):
                # The nearly undamped Gauss-Newton step is negligible: converged, no evaluation.
                return LsqResult(
                    theta,
                    cost,
                    r,
                    J,
                    STATUS_CONVERGED,
                    iterations,
                    **counts,
                    history=history,
                    active=_full_mask(active, free_idx, p_all),
                )
            trial_cost, trial_r, trial_J = evaluate(trial, settings.jacobian_at_trials)
            if trial_cost < cost:
                accepted = True
                break
            lam *= settings.lam_up
        if not accepted:
            status = STATUS_CONVERGED  # no descent left at machine precision
            break
        decrease = (cost - trial_cost) / max(cost, 1e-300)
        theta, cost, r = trial, trial_cost, trial_r
        if trial_J is None:
            _, r_j, trial_J = evaluate(theta, True)
            if trial_J is None or not np.all(np.isfinite(trial_J)):
                status = STATUS_DIVERGED
                J = trial_J
                break
            r = r_j
        J = trial_J
        history.append(cost)
        lam = max(lam / settings.lam_down, 1e-9)
        if decrease <= settings.ftol:
            status = STATUS_CONVERGED
            break
    return LsqResult(
        theta,
        cost,
        r,
        J,
        status,
        iterations,
        **counts,
        history=history,
        active=_full_mask(active, free_idx, p_all),
    )


def _full_mask(mask_free: np.ndarray, free_idx: np.ndarray, p_all: int) -> np.ndarray:
    out = np.zeros(p_all, bool)
    out[free_idx] = mask_free
    return out


def covariance(
    J: np.ndarray,
    ssr: float,
    *,
    free: np.ndarray | None = None,
    prior_precision: np.ndarray | None = None,
    inflate: float = 1.0,
    dof: int | None = None,
) -> np.ndarray:
    """Parameter covariance from the Jacobian at the solution (Gauss-Newton information).

    ``cov = (J_f^T J_f / s2 + Lambda_prior)^-1 * inflate`` on the free parameters ``f`` with
    ``s2 = ssr / dof`` the residual variance (``dof`` default ``m - p_free``); rows and
    columns of parameters not free are zero. ``inflate`` > 1 widens it when residuals are
    correlated (e.g. ``m / n_eff``).
    Raises ``numpy.linalg.LinAlgError`` when the information matrix is singular.
    """
    return covariance_from_gram(
        _gram(J),
        ssr,
        J.shape[0],
        free=free,
        prior_precision=prior_precision,
        inflate=inflate,
        dof=dof,
    )


def _free_indices(free, p_all: int) -> np.ndarray:
    free_idx = np.arange(p_all) if free is None else np.asarray(free)
    if free_idx.dtype == bool:
        free_idx = np.flatnonzero(free_idx)
    return free_idx


def covariance_from_gram(
    gram: np.ndarray,
    ssr: float,
    m: int,
    *,
    free: np.ndarray | None = None,
    prior_precision: np.ndarray | None = None,
    inflate: float = 1.0,
    dof: int | None = None,
) -> np.ndarray:
    """:func:`covariance` from ``gram = J^T J`` (P, P) and the number of residuals ``m``: the
    form an incremental fit keeps (sums over windows), no Jacobian needed."""
    p_all = gram.shape[0]
    free_idx = _free_indices(free, p_all)
    prec = np.zeros(p_all) if prior_precision is None else np.asarray(prior_precision, float)
    s2 = ssr / max(m - free_idx.size if dof is None else dof, 1)
    info = gram[np.ix_(free_idx, free_idx)] / max(s2, 1e-300) + np.diag(prec[free_idx])
    cov_f = np.linalg.inv(info) * inflate
    cov = np.zeros((p_all, p_all))
    cov[np.ix_(free_idx, free_idx)] = cov_f
    return cov


def window_scores(J: np.ndarray, r: np.ndarray, n_windows: int) -> np.ndarray:
    """Per-window scores ``J_w^T r_w`` (n_windows, p) of residuals stored window by window
    (``r`` (n_windows * k,), ``J`` (n_windows * k, p), the rows of window w contiguous)."""
    p = J.shape[1]
    return np.einsum("wkp,wk->wp", J.reshape(n_windows, -1, p), r.reshape(n_windows, -1))


def hac_covariance(
    J: np.ndarray,
    r: np.ndarray,
    n_windows: int,
    lag: int,
    *,
    free: np.ndarray | None = None,
    prior_precision: np.ndarray | None = None,
) -> np.ndarray:
    """Parameter covariance that holds under model error and correlated residuals.

    The residuals come in ``n_windows`` windows in time order (the rows of window ``w`` are
    contiguous in ``J`` and ``r``). The data part is the sandwich ``A^-1 B A^-1`` with
    ``A = J_f^T J_f`` (the Gauss-Newton Hessian of ``||r||^2 / 2``) and ``B`` the Newey-West
    (Bartlett kernel) estimate of the variance of the gradient ``sum_w s_w``, ``s_w = J_w^T
    r_w`` the window's score (centred)::

        G_l = sum_w s_w s_{w-l}^T
        B = G_0 + sum_{l=1..lag} (1 - l / (lag + 1)) (G_l + G_l^T)

    ``B`` takes the residuals as they are: their actual size (model error included, not the
    noise model's), their correlation within a window, between overlapping windows and over
    ``lag`` windows of time (a model error that persists over seconds of driving). With
    independent residuals of unit variance and a correct model ``B ~ A`` and this is the
    Gauss-Newton covariance ``A^-1``. A Gaussian prior adds its precision to the robust
    information: ``cov = (A B^-1 A + Lambda_prior)^-1`` (a parameter the data do not inform
    keeps the prior's variance). Rows and columns of parameters not free are zero.
    Raises ``numpy.linalg.LinAlgError`` when the information matrix is singular.
    """
    m, p_all = J.shape
    if n_windows < 1 or m % n_windows:
        raise ValueError(f"hac_covariance: {m} residual rows do not split into {n_windows} windows")
    return hac_covariance_from_scores(
        _gram(J), window_scores(J, r, n_windows), lag, free=free, prior_precision=prior_precision
    )


def hac_covariance_from_scores(
    gram: np.ndarray,
    scores: np.ndarray,
    lag: int,
    *,
    free: np.ndarray | None = None,
    prior_precision: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`hac_covariance` from ``gram = J^T J`` (P, P) and the windows' scores ``J_w^T r_w``
    (n_windows, P) in time order: the form an incremental fit keeps (sums per window)."""
    p_all = gram.shape[0]
    free_idx = _free_indices(free, p_all)
    n_windows = scores.shape[0]
    prec = np.zeros(p_all) if prior_precision is None else np.asarray(prior_precision, float)
    A = gram[np.ix_(free_idx, free_idx)]
    s = scores[:, free_idx]
    s = s - s.mean(axis=0)
    B = s.T @ s
    if not np.trace(B) > 0.0:  # residuals exactly zero (noise-free data, a perfect model)
        return np.zeros((p_all, p_all))
    for lag_i in range(1, min(int(lag), n_windows - 1) + 1):
        g = s[lag_i:].T @ s[:-lag_i]
        B += (1.0 - lag_i / (lag + 1.0)) * (g + g.T)
    info = A @ np.linalg.pinv(B, hermitian=True) @ A + np.diag(prec[free_idx])
    cov_f = np.linalg.inv(info)
    cov = np.zeros((p_all, p_all))
    cov[np.ix_(free_idx, free_idx)] = cov_f
    return cov
