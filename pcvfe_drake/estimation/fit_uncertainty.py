"""Uncertainty and identifiability of a fit, and the assembly of its :class:`FitResult`.

Identifiability
---------------
In the ST model mu enters only as ``mu * C_Sf`` and ``mu * C_Sr``. By default only mu is fitted
and the stiffnesses stay at the vehicle's nominal values. Joint fits take Gaussian priors
(``FitOptions.prior_sigma``, mean = the vehicle's nominal values). Every result reports standard
deviations from the Gauss-Newton information matrix ``J^T J / s2 + Lambda_prior`` (``s2`` the
residual variance estimate ``SSR / (n - p)``; ``Lambda_prior`` the prior precision) and a warning
when the (parameter-scaled) information matrix is ill-conditioned.

Standard deviations (``FitOptions.covariance``): by default (``hac``) the sandwich ``A^-1 B A^-1``
with ``B`` a Newey-West estimate of the variance of the gradient over the time-ordered windows
(``least_squares.hac_covariance``), combined with the prior as ``(A B^-1 A + Lambda_prior)^-1``.
It counts the residuals as they are (model error included) and their correlation within a
window, between overlapping windows and over ``hac_lag_s`` of driving. ``iid``: the Gauss-Newton
``(J^T J / s2 + Lambda_prior)^-1`` (``s2`` the residual variance estimate ``SSR / (n - p)``), which
treats the residuals as independent; overlapping windows and correlated model errors make it
optimistic (docs/fitting.md, "Uncertainty").
"""

from __future__ import annotations

import math
import time

import numpy as np

from pcvfe_drake.estimation.fit_dataset import SKIP_REASONS, WindowDataset
from pcvfe_drake.estimation.fit_options import (
    STATUS_DIVERGED,
    STATUS_TOO_LITTLE_DATA,
    FitOptions,
    FitResult,
    with_model_error,
)
from pcvfe_drake.estimation.fit_quality import assess
from pcvfe_drake.models import least_squares as lsq
from pcvfe_drake.vehicle.params import THETA_NAMES, VehicleParams
from pcvfe_drake.vehicle.single_track import NTHETA


def uncertainty(
    theta: np.ndarray,
    R: np.ndarray,
    J: np.ndarray,
    options: FitOptions,
    params: VehicleParams,
    t0: np.ndarray | None = None,
    dt: float = 0.0,
) -> tuple[np.ndarray, float, bool, list[str]]:
    """Standard deviations, condition number, ill-conditioned flag and warnings at ``theta``.

    ``R`` (windows, H, 7) and ``J`` (windows, H, 7, 3) at ``theta``, windows in time order;
    ``t0`` their start times [s] and ``dt`` the step [s] (the ``hac`` covariance's lag)."""
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
    info = gram(Jf)
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
    try:
        if options.covariance == "hac":
            n_win = R.shape[0]
            cov = lsq.hac_covariance(
                Jf,
                r,
                n_win,
                hac_lag(t0, R.shape[1] * dt, options.hac_lag_s),
                prior_precision=prior_prec,
            )
        else:
            cov = np.linalg.inv(info / max(s2, 1e-300) + np.diag(prior_prec))
        diag = np.diag(cov)
        std[free] = np.sqrt(np.where(diag >= 0, diag, np.inf))
    except np.linalg.LinAlgError:
        std[free] = np.inf
    mu_i = THETA_NAMES.index("mu")
    if mu_i in free:  # the model-error budget (FitOptions.model_error_rel)
        std[mu_i] = with_model_error(theta[mu_i], std[mu_i], options.model_error_rel)
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


def hac_lag(t0: np.ndarray | None, span_s: float, lag_s: float) -> int:
    """The ``hac`` covariance's lag in windows: windows that start within a window's span
    ``span_s`` plus ``lag_s`` of each other (the spacing: the median positive step of the start
    times ``t0``; without two distinct starts: 1)."""
    if t0 is None or len(t0) < 2:
        return 1
    d = np.diff(np.asarray(t0, dtype=float))
    d = d[d > 0]
    if d.size == 0:
        return 1
    return max(1, int(math.ceil((span_s + lag_s) / float(np.median(d)) - 1e-9)))


def gram(Jf: np.ndarray) -> np.ndarray:
    """``Jf^T Jf`` for a tall, thin ``Jf`` (n, p); einsum avoids the slow BLAS path of matmul for
    this shape (tens of ms for n ~ 1e5 under load, against ~0.1 ms)."""
    return np.einsum("ni,nj->ij", Jf, Jf)


def residual_rms(R: np.ndarray, weights: np.ndarray) -> np.ndarray:
    if R.size == 0:
        return np.full(7, np.nan)
    return np.sqrt(np.mean((R / weights) ** 2, axis=(0, 1)))


def no_fit_result(
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


def final_result(
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
    std, cond, ill, warnings = uncertainty(theta, R, J, options, params, data.t0, data.dt)
    loss = float(np.sum(R * R)) / (data.n_windows * data.horizon)
    quality: dict = {}
    if not (math.isfinite(loss) and np.all(np.isfinite(theta))):
        status = STATUS_DIVERGED
    else:
        quality, checks = assess(theta, std, R, J, data, options, params, loss)
        warnings.extend(checks)
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
        residual_rms=residual_rms(R, options.weights),
        rollouts=rollouts,
        quality=quality,
    )
