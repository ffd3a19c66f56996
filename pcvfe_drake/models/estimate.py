"""Fit the workbench model on log windows: multi-step rollout least squares, Levenberg-Marquardt.

The cost is the sum of squared *whitened* prediction errors (error / per-state noise scale) of
rollouts of ``horizon`` steps started from the measured states, over the states in
``FIT_STATES`` (delta, v, psi, psi_dot, beta). Positions are left out: their multi-step error is
dominated by the initial heading noise times the distance travelled.

Sensitivities: central finite differences in the parameters, computed in *one* vectorised
rollout (the 2P + 1 parameter vectors are stacked along the batch axis with the windows), with
steps of 1e-4 x each parameter's typical scale. The effect hooks are arbitrary user code, so
finite differences keep every effect differentiable without hand-written Jacobians; the ST part
agrees with ``pcvfe_drake.vehicle.single_track``'s exact Jacobians to the accuracy of central
differences. Where mu alone is fitted on a model whose rollout is compiled (the context
fitter's case), its sensitivity is exact instead: forward mode through the same RK4 steps
(``WorkbenchModel.mu_sensitivity``), one rollout with a tangent rather than three rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.models import least_squares as lsq
from pcvfe_drake.models.data import DriveData
from pcvfe_drake.models.model import WorkbenchModel, rollout_errors
from pcvfe_drake.vehicle.single_track import BETA, DELTA, PSI, PSI_DOT, V

FIT_STATES = (DELTA, V, PSI, PSI_DOT, BETA)
"""States (indices in CommonRoad order) in the fit cost and the headline multi-step error."""
FD_STEP = 1e-4
"""Finite-difference step relative to each parameter's scale."""


@dataclass
class FitResult:
    """A fitted model.

    Attributes:
        model: the model.
        theta: fitted parameter vector (model.param_names order).
        std: 1-sigma uncertainty per parameter (inflated for correlated errors; see ``fit``).
        cost: training sum of squared whitened errors.
        n_residuals: number of scalar residuals in ``cost``.
        n_eff: effective number of independent observations (for tests and uncertainties).
        n_iter: Levenberg-Marquardt iterations.
        converged: whether the relative cost change fell below the tolerance.
        cov: parameter covariance (P, P) behind ``std`` (rows and columns of parameters at a
            bound, uninformed or held fixed are zero), None when it could not be formed.
    """

    model: WorkbenchModel
    theta: np.ndarray
    std: np.ndarray
    cost: float
    n_residuals: int
    n_eff: float
    n_iter: int
    converged: bool
    history: list[float] = field(default_factory=list)
    informed: np.ndarray | None = None
    cov: np.ndarray | None = None
    residuals: np.ndarray | None = field(default=None, repr=False)
    """The whitened residuals at ``theta`` (window by window), kept for an incremental refit."""
    jacobian: np.ndarray | None = field(default=None, repr=False)
    """Their Jacobian (fixed parameters' columns zero), kept for an incremental refit."""

    def at_bound(self) -> np.ndarray:
        """Per parameter: whether the fit ended on one of its bounds."""
        lo, hi = self.model.bounds()
        tol = 1e-6 * (hi - lo)
        return (self.theta <= lo + tol) | (self.theta >= hi - tol)

    def params_dict(self, only_effects: bool = False, effect: str | None = None) -> dict:
        """{name: {value, std, unit, informed, at_bound}}; ``informed`` is False for a
        parameter the training windows carry no information on (e.g. the friction of a
        context that no training window visits): it keeps its starting value. A parameter
        at a bound has no defined uncertainty (``std`` NaN, null in JSON). ``effect``: only
        that effect's parameters."""
        out = {}
        informed = np.ones(self.theta.size, bool) if self.informed is None else self.informed
        bound = self.at_bound()
        rows = zip(self.model.params, self.theta, self.std, informed, bound, strict=True)
        for p, value, s, inf, at in rows:
            if (only_effects and p.effect is None) or (effect is not None and p.effect != effect):
                continue
            out[p.name] = {
                "value": float(value),
                "std": float("nan") if at else float(s),
                "unit": p.unit,
                "informed": bool(inf),
                "at_bound": bool(at and abs(value - p.null) > 1e-9 * (p.upper - p.lower)),
            }
        return out


def whitened_errors(
    model: WorkbenchModel,
    theta_rows: np.ndarray,
    data: DriveData,
    starts: np.ndarray,
    horizon: int,
    burn_in: int = 0,
) -> np.ndarray:
    """Errors (N, horizon - burn_in, len(FIT_STATES)) divided by the log's noise scales,
    leaving out the first ``burn_in`` steps of each window."""
    return _whitened(model.errors(theta_rows, data, starts, horizon), data, burn_in)


def _whitened(err: np.ndarray, data: DriveData, burn_in: int) -> np.ndarray:
    """``err`` (N, steps, 7), per fitted state divided by its noise scale, without the first
    ``burn_in`` steps."""
    idx = list(FIT_STATES)
    return err[:, burn_in:, idx] / data.sigma[idx]


def _residuals_and_jacobian(
    model, theta, data, starts, horizon, with_jacobian, burn_in=0, cols=None
):
    """Residuals (whitened, flattened) and their finite-difference Jacobian (columns ``cols``
    only, default all; the other columns are zero) from one batched rollout; mu's column
    exact where it is the only one and the rollout is compiled (:func:`_exact_mu`)."""
    n_p = model.n_params
    n = starts.size
    if not with_jacobian:
        r = whitened_errors(model, theta, data, starts, horizon, burn_in).reshape(-1)
        return r, None
    cols = np.arange(n_p) if cols is None else np.asarray(cols, dtype=int)
    exact = _exact_mu(model, theta, data, starts, horizon, burn_in, cols)
    if exact is not None:
        return exact
    n_c = cols.size
    h = FD_STEP * model.scales()
    rows = np.tile(theta, (2 * n_c + 1, 1))
    for i, j in enumerate(cols):
        rows[1 + 2 * i, j] += h[j]
        rows[2 + 2 * i, j] -= h[j]
    theta_rows = np.repeat(rows, n, axis=0)
    all_starts = np.tile(starts, 2 * n_c + 1)
    e = whitened_errors(model, theta_rows, data, all_starts, horizon, burn_in)
    e = e.reshape(2 * n_c + 1, -1)
    r = e[0]
    jac = np.zeros((r.size, n_p))
    for i, j in enumerate(cols):
        jac[:, j] = (e[1 + 2 * i] - e[2 + 2 * i]) / (2.0 * h[j])
    return r, jac


def _exact_mu(model, theta, data, starts, horizon, burn_in, cols):
    """Residuals and Jacobian with mu's column exact (``WorkbenchModel.mu_sensitivity``) when
    mu of a one-context model is the only column asked for; None otherwise."""
    if cols.size != 1 or model.params[int(cols[0])].name != "mu" or np.ndim(theta) != 1:
        return None
    out = model.mu_sensitivity(theta, data, starts, horizon)
    if out is None:
        return None
    Z, sens = out
    r = _whitened(rollout_errors(Z, data, starts, horizon), data, burn_in).reshape(-1)
    jac = np.zeros((r.size, model.n_params))
    jac[:, int(cols[0])] = _whitened(sens[:, 1:], data, burn_in).reshape(-1)
    return r, jac


def training_cost(model, theta, data, starts, horizon, burn_in: int = 0) -> float:
    r, _ = _residuals_and_jacobian(model, theta, data, starts, horizon, False, burn_in)
    return float(r @ r)


def training_costs(model, thetas, data, starts, horizon, burn_in: int = 0) -> list[float]:
    """:func:`training_cost` of each parameter vector in ``thetas`` from one batched rollout
    (the vectors stacked along the batch axis, as the finite differences are): on a handful of
    windows a rollout's cost is numpy's per-call overhead, whatever its rows."""
    thetas = np.asarray(thetas, dtype=float)
    n = starts.size
    rows = np.repeat(thetas, n, axis=0)
    e = whitened_errors(model, rows, data, np.tile(starts, len(thetas)), horizon, burn_in)
    e = e.reshape(len(thetas), -1)
    return [float(r @ r) for r in e]


def fit(
    model: WorkbenchModel,
    data: DriveData,
    starts: np.ndarray,
    horizon: int,
    theta0: np.ndarray | None = None,
    candidates: list[np.ndarray] | None = None,
    max_iter: int = 25,
    rtol: float = 1e-7,
    overlap: float = 1.0,
    burn_in: int = 0,
    fixed: np.ndarray | None = None,
    prior_mean: np.ndarray | None = None,
    prior_sd: np.ndarray | None = None,
    hac_lag: int | None = None,
    jacobian_at_trials: bool = False,
) -> FitResult:
    """Levenberg-Marquardt fit of all model parameters within their bounds (projected steps).

    Args:
        model: the model to fit.
        data: the log.
        starts: training window starts.
        horizon: steps per window.
        theta0: starting vector (default: the model's initial values).
        candidates: further starting vectors; the one with the lowest cost is refined.
        max_iter: iteration limit.
        rtol: stop when an accepted step lowers the cost by less than this fraction.
        overlap: windows per non-overlapping window (horizon / stride), for ``n_eff``.
        burn_in: leading steps of each window left out of the cost. Noise in the measured
            initial yaw rate and slip starts a transient whose size depends on the parameters;
            leaving out its first ~0.25 s removes most of the bias that this noise would put
            on stiffness and lag estimates.
        fixed: boolean mask (P,) of parameters held at their starting value (not fitted; std
            NaN), e.g. effect parameters found by ``pcvfe diagnose`` (default: none).
        prior_mean, prior_sd: an optional Gaussian prior per parameter (sd inf: none), in the
            cost as ``((theta - mean) / sd)^2`` and in the covariance.
        hac_lag: None (default): ``std`` as below; an integer: ``std`` from the sandwich with a
            Newey-West estimate over the windows in the order of ``starts`` (time order), with
            this many lags (``least_squares.hac_covariance``; the context fitter's choice).
        jacobian_at_trials: roll each trial point out with its finite-difference rows (one
            rollout per accepted step instead of two, a rejected one costing the rows of the
            differences): the choice where a rollout's cost is its per-call overhead (few
            windows and fitted parameters, the context fitter); default False (each
            Jacobian costs 2P + 1 times the rows of a trial).
    Returns:
        FitResult. ``std`` = sqrt(diag(s^2 (J^T J)^-1)) with s^2 = cost / (n_residuals - P),
        multiplied by sqrt(n_residuals / n_eff): errors inside a window are strongly
        correlated, so each window and state counts as one observation (``n_eff`` = windows /
        overlap x states); with ``hac_lag`` the sandwich's.
    """
    starts = np.asarray(starts, dtype=int)
    if starts.size == 0:
        raise ValueError(
            f"drive log {data.source}: no usable training windows (need stretches of "
            f"{horizon * data.dt:g} s with v >= 1 m/s inside one context)"
        )
    lo, hi = model.bounds()
    scale = model.scales()
    theta = model.initial_theta() if theta0 is None else np.clip(theta0, lo, hi)
    if candidates:
        options = [theta] + [np.clip(c, lo, hi) for c in candidates]
        costs = training_costs(model, options, data, starts, horizon, burn_in)
        theta = options[int(np.argmin(costs))]

    fixed = np.zeros(model.n_params, bool) if fixed is None else np.asarray(fixed, bool)
    precision = np.zeros(model.n_params)
    if prior_sd is not None:
        precision = 1.0 / np.asarray(prior_sd, dtype=float) ** 2
    mean = theta.copy() if prior_mean is None else np.asarray(prior_mean, dtype=float)
    fitted_cols = np.flatnonzero(~fixed)

    def fun(th, need_jacobian):
        r, jac = _residuals_and_jacobian(
            model, th, data, starts, horizon, need_jacobian, burn_in, fitted_cols
        )
        if not np.all(np.isfinite(r)):
            r = np.full_like(r, np.inf)
        return r, jac

    out = lsq.solve(
        fun,
        theta,
        lo,
        hi,
        scale,
        free=~fixed,
        prior_mean=mean,
        prior_precision=precision,
        settings=lsq.LsqSettings(
            max_iterations=max_iter,
            ftol=rtol,
            xtol=1e-9,
            lam_up=4.0,
            lam_down=3.0,
            max_rejections=8,
            jacobian_at_trials=jacobian_at_trials,
            predicted_check=False,
        ),
    )
    theta, r, jac, it = out.theta, out.r, out.J, out.iterations
    cost = float(r @ r)  # the data's part (the prior's is in out.cost)
    converged, history = out.converged, out.history
    n_res = r.size
    n_eff = max(starts.size / max(overlap, 1.0) * len(FIT_STATES), model.n_params + 1.0)
    informed = np.any(jac != 0.0, axis=0) | fixed
    std, cov = parameter_std(
        model,
        theta,
        fixed,
        informed,
        precision,
        lsq._gram(jac),
        lsq.window_scores(jac, r, starts.size) if hac_lag is not None else None,
        cost,
        n_res,
        n_eff,
        hac_lag,
    )
    return FitResult(
        model,
        theta,
        std,
        cost,
        n_res,
        n_eff,
        it,
        converged,
        history,
        informed,
        cov,
        residuals=r,
        jacobian=jac,
    )


def parameter_std(
    model: WorkbenchModel,
    theta: np.ndarray,
    fixed: np.ndarray,
    informed: np.ndarray,
    precision: np.ndarray,
    gram: np.ndarray,
    scores: np.ndarray | None,
    ssr: float,
    n_res: int,
    n_eff: float,
    hac_lag: int | None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """``(std, cov)`` of a fit at ``theta`` from ``gram = J^T J`` and, with ``hac_lag``, the
    windows' scores ``J_w^T r_w`` (see :func:`fit`'s Returns); a parameter on a bound gets std
    0, an uninformed or fixed one NaN. Shared by the batch fit and the incremental one
    (``pcvfe_drake.estimation.effect_fit``), which keeps these sums instead of a Jacobian."""
    lo, hi = model.bounds()
    free = ~((theta <= lo) | (theta >= hi)) & informed & ~fixed
    std = np.full(model.n_params, np.nan)
    cov = None
    if free.any():
        try:
            if hac_lag is not None:
                cov = lsq.hac_covariance_from_scores(
                    gram, scores, hac_lag, free=free, prior_precision=precision
                )
            else:
                inflate = n_res / n_eff
                cov = lsq.covariance_from_gram(
                    gram,
                    ssr,
                    n_res,
                    free=free,
                    prior_precision=precision * inflate,  # (J^T J / (s2 inflate) + prior)^-1
                    inflate=inflate,
                    dof=n_res - model.n_params,
                )
            std[free] = np.sqrt(np.maximum(np.diag(cov)[free], 0.0))
        except np.linalg.LinAlgError:
            pass
    std[~free] = 0.0
    std[~informed | fixed] = np.nan
    return std, cov
