"""The fitting loss through the ST dynamics (paper eq. 5a-5d) and its exact derivatives.

Loss
----
For a window (``pcvfe_drake.estimation.fit_dataset``) the ST model is rolled out from the measured
initial state (5b) with the recorded inputs (5c, RK4 at the log step) and compared with the
measured states at steps 1..H. The residual of state j at step k is

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
"""

from __future__ import annotations

import math

import numpy as np

from pcvfe_drake.estimation.fit_dataset import WindowDataset
from pcvfe_drake.estimation.fit_options import DEFAULT_STATE_SCALES, MAX_STEP_S
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import NTHETA, PSI, rollout, wrap_angle


def check_theta(theta, params: VehicleParams) -> np.ndarray:
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
    theta = check_theta(theta, params)
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
