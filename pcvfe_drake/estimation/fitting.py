"""Context-specific friction fitting through the ST dynamics (paper eq. 5a-5d).

Modules: ``fit_options`` (options, results, bounds, residual scales), ``fit_loss`` (the loss,
eq. 5a-5d, and its exact gradient), ``fit_uncertainty`` (standard deviations, identifiability
warnings, the result), this one (the solvers and :func:`fit_contexts`). The names of all four
are importable from here.

Solvers
-------
* :func:`fit_gauss_newton` (default): a bounded Levenberg-Marquardt (Gauss-Newton with
  Marquardt damping and projection onto the bounds, an active set at the bounds) using the exact
  rollout sensitivities ``dX/dtheta`` of ``pcvfe_drake.vehicle.single_track.rollout``;
  warm-started from the given theta (e.g. the previous estimate).
* :func:`fit_adam`: the paper's optimiser: Adam, learning rate 0.01, batch 1024, gradients through
  the rollout (exact, from the same sensitivities), projected onto the bounds.

Identifiability: see ``fit_uncertainty``; by default only mu is fitted (it enters the ST model
only as ``mu * C_Sf`` and ``mu * C_Sr``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Hashable, Mapping

import numpy as np

from pcvfe_drake.estimation.fit_dataset import SKIP_REASONS, WindowDataset, WindowSplit
from pcvfe_drake.estimation.fit_loss import (
    check_theta,
    window_loss,
    window_loss_and_gradient,
    window_residuals,
)
from pcvfe_drake.estimation.fit_options import (
    ADAM_BATCH_SIZE,
    ADAM_LEARNING_RATE,
    DEFAULT_STATE_SCALES,
    JOINT_PRIOR_REL_SIGMA,
    MAX_STEP_S,
    MU_BOUNDS,
    STATUS_CONVERGED,
    STATUS_DIVERGED,
    STATUS_MAX_ITERATIONS,
    STATUS_TARGET_REACHED,
    STATUS_TOO_LITTLE_DATA,
    STIFFNESS_REL_BOUNDS,
    FitOptions,
    FitResult,
    joint_options,
)
from pcvfe_drake.estimation.fit_uncertainty import final_result, no_fit_result
from pcvfe_drake.models import least_squares as lsq
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import NTHETA

__all__ = [
    "ADAM_BATCH_SIZE",
    "ADAM_LEARNING_RATE",
    "DEFAULT_STATE_SCALES",
    "JOINT_PRIOR_REL_SIGMA",
    "MAX_STEP_S",
    "MU_BOUNDS",
    "SOLVERS",
    "STATUS_CONVERGED",
    "STATUS_DIVERGED",
    "STATUS_MAX_ITERATIONS",
    "STATUS_TARGET_REACHED",
    "STATUS_TOO_LITTLE_DATA",
    "STIFFNESS_REL_BOUNDS",
    "FitOptions",
    "FitResult",
    "fit_adam",
    "fit_contexts",
    "fit_gauss_newton",
    "joint_options",
    "window_loss",
    "window_loss_and_gradient",
    "window_residuals",
]


def _start(theta0, params: VehicleParams, data, options: FitOptions, solver: str):
    """The start shared by both solvers: ``(theta, lower, upper, no_fit)`` with theta0 checked
    and clipped into the bounds, and ``no_fit`` the result to return when there are too few
    windows (else None)."""
    lower, upper = options.bounds(params)
    theta = np.clip(check_theta(theta0, params), lower, upper)
    if data is None or data.n_windows < options.min_windows:
        return (
            theta,
            lower,
            upper,
            no_fit_result(theta, data, options, solver, STATUS_TOO_LITTLE_DATA),
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
        result = no_fit_result(theta, data, options, "gauss_newton", STATUS_DIVERGED)
        result.warnings.append("the rollout loss is not finite at the starting theta")
        result.elapsed_s = time.perf_counter() - start_time
        return result

    def levenberg_marquardt(theta, cost, R, J, windows, max_iterations, xtol, ftol):
        """Bounded LM (the shared core) from theta (R, J evaluated there); the final state."""
        shape = R.shape

        def fun(th, need_jacobian):
            _, R_t, J_t = objective(th, windows)
            return R_t.reshape(-1), J_t.reshape(-1, NTHETA)

        out = lsq.solve(
            fun,
            theta,
            lower,
            upper,
            np.maximum(np.abs(theta), 1e-6),  # work in parameter-relative units
            free=free,
            prior_mean=prior_mean,
            prior_precision=precision,
            settings=lsq.LsqSettings(max_iterations=max_iterations, xtol=xtol, ftol=ftol),
            start=(R.reshape(-1), J.reshape(-1, NTHETA)),
        )
        n = out.r.size // int(np.prod(shape[1:]))
        R_o = out.r.reshape((n, *shape[1:]))
        J_o = out.J.reshape((n, *shape[1:], NTHETA))
        return out.theta, out.cost, R_o, J_o, out.status, out.iterations

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
    return final_result(
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
    return final_result(
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
