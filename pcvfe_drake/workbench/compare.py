"""Compare a fitted model with measurements on held-out data.

* fit % per state in MATLAB's NRMSE form ``100 (1 - |y - yhat| / |y - mean(y)|)`` (2-norms over
  samples), for k-step-ahead predictions and for free-run simulation;
* k-step prediction RMS error per state for several horizons;
* the *multi-step error*: RMS of the whitened errors (error / noise scale) of rollouts over
  ``horizon`` steps on held-out windows, over the states in ``FIT_STATES``;
* the headline *model error*: the part of that error the measurement noise does not explain,
  ``sqrt(max(MSE - MSE_noise, 0))``. ``MSE_noise`` is what a perfect model would score: 1 per
  state for the noise on the measured end point (errors are whitened) plus the spread that
  the noise on the measured initial state causes, obtained by rolling the fitted model out
  from initial states perturbed with noise of the log's estimated size (fixed seed). Error
  drops ("adding the effect removes 60 % of the held-out error") use the model error, so they
  do not depend on how noisy the sensors are.
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.models.data import MIN_SPEED_MPS, DriveData, block_ids, heldout_blocks
from pcvfe_drake.models.estimate import FIT_STATES
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.vehicle.single_track import NX, PSI, STATE_NAMES, wrap_angle

HORIZONS_S = (0.0, 0.5, 1.0, 2.0)
"""k-step horizons [s] reported (0 means one sample step)."""


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """MATLAB's fit %: 100 (1 - ||y - yhat|| / ||y - mean(y)||)."""
    y = np.asarray(y, dtype=float)
    denom = np.linalg.norm(y - y.mean())
    if denom <= 0:
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / denom))


def horizon_steps(data: DriveData, horizons_s=HORIZONS_S) -> list[int]:
    return sorted({max(1, int(round(h / data.dt))) for h in horizons_s})


def multistep_error(err: np.ndarray, data: DriveData) -> float:
    """RMS of whitened errors over FIT_STATES of an error array (N, H, 7)."""
    idx = list(FIT_STATES)
    return float(np.sqrt(np.mean((err[:, :, idx] / data.sigma[idx]) ** 2)))


def noise_rollouts(
    model: WorkbenchModel, theta: np.ndarray, data: DriveData, starts: np.ndarray, horizon: int
):
    """Errors of the windows and what a perfect model would score, in one vectorised rollout.

    Returns ``(err, floor_w, null_w)``: prediction minus measurement (N, horizon, 7); per
    window the whitened MSE a perfect model would get from measurement noise alone (the
    noise on the end points contributes 1 per state, the noise on the initial state its
    spread through the model, from initial states perturbed with noise of the log's size);
    and one simulated draw per window of that MSE with a second, independent perturbation
    and end-point noise (for its variance when the model is right). Fixed seeds."""
    rng = np.random.default_rng(12345)
    n = starts.size
    sigma0 = data.sigma.copy()
    sigma0[2] = data.x0_delta_sigma
    x0 = data.x0[starts]
    stacked = np.concatenate(
        [x0, x0 + rng.standard_normal((n, NX)) * sigma0, x0 + rng.standard_normal((n, NX)) * sigma0]
    )
    Z = model.simulate(theta, data, np.tile(starts, 3), horizon, x0=stacked)
    clean, noisy, noisy2 = Z[:n], Z[n : 2 * n], Z[2 * n :]
    idx = np.asarray(starts)[:, None] + np.arange(1, horizon + 1)[None, :]
    err = clean[:, 1:, :NX] - data.x[idx]
    err[:, :, PSI] = wrap_angle(err[:, :, PSI])
    fit_idx = list(FIT_STATES)
    d = (noisy[:, 1:, fit_idx] - clean[:, 1:, fit_idx]) / data.sigma[fit_idx]
    d2 = (noisy2[:, 1:, fit_idx] - clean[:, 1:, fit_idx]) / data.sigma[fit_idx]
    floor_w = np.mean(d**2, axis=(1, 2)) + 1.0
    null_w = np.mean((d2 - rng.standard_normal(d2.shape)) ** 2, axis=(1, 2))
    return err, floor_w, null_w


def noise_floor_mse(
    model: WorkbenchModel, theta: np.ndarray, data: DriveData, starts: np.ndarray, horizon: int
) -> float:
    """Whitened MSE a perfect model would get from measurement noise alone (see
    :func:`noise_rollouts`)."""
    return float(np.mean(noise_rollouts(model, theta, data, starts, horizon)[1]))


def free_run(model: WorkbenchModel, theta: np.ndarray, data: DriveData, n_blocks: int = 6):
    """Free-run simulation over each held-out block that is one context at v >= 1 m/s.

    Returns a list of (sample indices (L,), simulated ST states (L, 7)).
    """
    blocks = block_ids(data.n, n_blocks)
    out = []
    for b in heldout_blocks(n_blocks):
        idx = np.flatnonzero(blocks == b)
        if idx.size < 3:
            continue
        ok = (data.x[idx, 3] >= MIN_SPEED_MPS) & (data.context[idx] == data.context[idx[0]])
        # the longest run of usable samples from the block start
        stop = int(np.argmin(ok)) if not ok.all() else idx.size
        if stop < 3:
            continue
        idx = idx[:stop]
        Z = model.simulate(theta, data, idx[:1], idx.size - 1)
        out.append((idx, Z[0, :, :NX]))
    return out


def evaluate(
    model: WorkbenchModel,
    theta: np.ndarray,
    data: DriveData,
    starts: np.ndarray,
    horizon: int,
    n_blocks: int = 6,
    with_free_run: bool = True,
) -> dict:
    """Held-out comparison of one fitted model; JSON-ready numbers plus arrays for plots.

    Args:
        starts: held-out window starts (all windows of ``horizon`` steps).
        with_free_run: also simulate each held-out block from its start (fit % free run).
    """
    err, floor_w, null_w = noise_rollouts(model, theta, data, starts, horizon)
    idx = list(FIT_STATES)
    mse_w = np.mean((err[:, :, idx] / data.sigma[idx]) ** 2, axis=(1, 2))
    mse = float(np.mean(mse_w))
    floor = float(np.mean(floor_w))
    out: dict = {
        "model_error": float(np.sqrt(max(mse - floor, 0.0))),
        "multistep_error": float(np.sqrt(mse)),
        "noise_floor": float(np.sqrt(floor)),
        "n_windows": int(starts.size),
    }
    kstep = {}
    fitp = {}
    for k in horizon_steps(data):
        if k > horizon:
            continue
        e = err[:, k - 1, :]
        y = data.x[starts + k]
        label = f"{k * data.dt:.3g}s"
        kstep[label] = {n: float(np.sqrt(np.mean(e[:, i] ** 2))) for i, n in enumerate(STATE_NAMES)}
        fitp[label] = {
            n: fit_percent(y[:, i], y[:, i] + e[:, i]) for i, n in enumerate(STATE_NAMES)
        }
    out["kstep_rmse"] = kstep
    out["fit_percent_kstep"] = fitp
    runs = free_run(model, theta, data, n_blocks) if with_free_run else []
    if runs:
        idx = np.concatenate([r[0] for r in runs])
        sim = np.concatenate([r[1] for r in runs])
        y = data.x[idx]
        out["fit_percent_free_run"] = {
            n: fit_percent(y[:, i], sim[:, i]) for i, n in enumerate(STATE_NAMES)
        }
        out["free_run_rmse"] = {
            n: float(np.sqrt(np.mean((sim[:, i] - y[:, i]) ** 2)))
            for i, n in enumerate(STATE_NAMES)
        }
    out["_err"] = err
    out["_mse_w"] = mse_w
    out["_floor_w"] = floor_w
    out["_null_w"] = null_w
    out["_free_run"] = runs
    return out


def public(result: dict) -> dict:
    """The JSON-ready part of an ``evaluate`` result (drops arrays)."""
    return {k: v for k, v in result.items() if not k.startswith("_")}
