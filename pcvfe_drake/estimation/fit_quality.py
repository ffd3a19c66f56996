"""Is a converged fit believable? Checks of the result against the data (docs/fitting.md,
"Quality warnings").

A solver converges on any data; these checks say when the friction it reports should not be
trusted:

* **at a bound**: a free parameter ended on its bound (within ``BOUND_REL_TOL``): the data push
  it beyond the physical range, typically a wrong unit, sign or bias in the log.
* **loss far above the noise**: the measurement noise of each state is estimated from the data
  themselves (4th differences along each window, robust to outliers:
  ``1.4826 MAD / sqrt(70)``); pure noise on the predicted states gives a loss of
  ``sum_j (sigma_j / s_j)^2`` (``s`` the residual scales; 7 when the noise equals the scales).
  The initial-state noise adds up to about as much again. A loss above
  ``LOSS_NOISE_RATIO_WARN`` times ``max(that, 1)`` is far more than the noise explains: a
  biased or mislabelled column, or a model error.
* **single samples dominate**: the shift of the estimate when one window is left out,
  ``H^-1 J_w^T r_w`` (one Gauss-Newton step; ``H`` the information matrix with the priors). A
  window that moves a parameter by more than ``INFLUENCE_STD`` standard deviations and more
  than ``INFLUENCE_REL`` of its value carries a corrupt sample (or an event the model lacks);
  the worst are listed with their start times.
* **data unlike a measurement**: a state whose noise estimate exceeds ``NOISIER_THAN_SCALE`` times
  its residual scale (garbage, a shuffled or mis-scaled column: it then also inflates the noise
  the loss is compared with), or that is constant over every window (not measured, e.g. a slip
  angle logged as 0), is weighted by the fit as a precise measurement: warned by name.
* **poor fit**: the fit percent ``100 (1 - ||error|| / ||x - mean x||)`` of the yaw rate and the
  side slip over all window steps, where the state is excited (std above
  ``EXCITATION_NOISE_FACTOR`` times its noise): below ``POOR_FIT_PERCENT`` the model explains
  little of what friction acts on.
"""

from __future__ import annotations

import math

import numpy as np

from pcvfe_drake.estimation.fit_dataset import WindowDataset
from pcvfe_drake.estimation.fit_options import FitOptions
from pcvfe_drake.models.data import EXCITATION_NOISE_FACTOR, sigma_from_fourth_difference_mad
from pcvfe_drake.vehicle.params import THETA_NAMES, VehicleParams
from pcvfe_drake.vehicle.single_track import BETA, NTHETA, NX, PSI_DOT, STATE_NAMES

BOUND_REL_TOL = 1e-6
LOSS_NOISE_RATIO_WARN = 5.0
INFLUENCE_STD = 3.0
INFLUENCE_REL = 0.01
POOR_FIT_PERCENT = 50.0
FIT_STATES = (PSI_DOT, BETA)
"""States whose fit percent is judged: the ones friction acts on."""
MAX_LISTED_WINDOWS = 5
NOISIER_THAN_SCALE = 5.0


def noise_sigma(data: WindowDataset) -> np.ndarray:
    """Measurement-noise std per state (7,), from the 4th differences along the windows; NaN
    when the windows are shorter than 5 samples."""
    if data.horizon < 5 or data.n_windows == 0:
        return np.full(NX, np.nan)
    d4 = np.diff(data.X, 4, axis=1).reshape(-1, NX)
    mad = np.median(np.abs(d4 - np.median(d4, axis=0)), axis=0)
    return sigma_from_fourth_difference_mad(mad)


def _fit_percent(error: np.ndarray, signal: np.ndarray) -> float:
    spread = float(np.linalg.norm(signal - signal.mean()))
    if spread <= 0:
        return math.nan
    return 100.0 * (1.0 - float(np.linalg.norm(error)) / spread)


def assess(
    theta: np.ndarray,
    std: np.ndarray,
    R: np.ndarray,
    J: np.ndarray,
    data: WindowDataset,
    options: FitOptions,
    params: VehicleParams,
    loss: float,
) -> tuple[dict, list[str]]:
    """The quality report (JSON-ready) and its warnings for a fit ending at ``theta``."""
    free = options.free_index
    names = [THETA_NAMES[i] for i in free]
    warnings: list[str] = []
    quality: dict = {}

    lower, upper = options.bounds(params)
    at_bound = []
    for i, name in zip(free, names, strict=True):
        for side, bound in (("lower", lower[i]), ("upper", upper[i])):
            if abs(theta[i] - bound) <= BOUND_REL_TOL * abs(bound):
                at_bound.append(name)
                warnings.append(
                    f"{name} = {theta[i]:.4g} sits on its {side} bound {bound:.4g}: the data push "
                    "it out of the physical range; check the log's units, signs and biases "
                    "(pcvfe fit's validation lists what it can), or an effect the model lacks "
                    "(pcvfe diagnose)"
                )
    quality["at_bound"] = at_bound

    sigma = noise_sigma(data)
    w = options.weights
    noise_loss = float(np.sum((sigma * w) ** 2)) if np.all(np.isfinite(sigma)) else float(NX)
    ratio = loss / max(noise_loss, 1.0) if math.isfinite(loss) else math.nan
    quality["noise_loss"] = noise_loss
    quality["loss_noise_ratio"] = ratio
    if ratio > LOSS_NOISE_RATIO_WARN:
        worst = int(np.argmax(np.mean(R * R, axis=(0, 1)))) if R.size else 0
        warnings.append(
            f"the loss {loss:.4g} is {ratio:.3g} times what the measurement noise explains "
            f"({max(noise_loss, 1.0):.3g}, noise estimated from the data); the largest errors are "
            f"in {STATE_NAMES[worst]}: a biased, mis-scaled or sign-flipped column, or a model "
            "error; the friction is not trustworthy"
        )

    scales = np.asarray(options.state_scales, dtype=float)
    noisy = [
        f"{STATE_NAMES[j]} (noise {sigma[j]:.3g} vs scale {scales[j]:.3g})"
        for j in range(NX)
        if math.isfinite(sigma[j]) and sigma[j] > NOISIER_THAN_SCALE * scales[j]
    ]
    flat = [STATE_NAMES[j] for j in range(NX) if data.n_windows and np.ptp(data.X[..., j]) == 0]
    quality["noisy_states"] = noisy
    quality["constant_states"] = flat
    if noisy:
        warnings.append(
            f"{', '.join(noisy)} far noisier than the residual scales assume "
            f"(> {NOISIER_THAN_SCALE:g}x): garbage or a mis-scaled column, which the fit weights "
            "as a precise measurement; check those columns"
        )
    if flat:
        warnings.append(
            f"{', '.join(flat)} constant in every window: not measured? the fit treats the "
            "constant as a measurement; log the real values"
        )

    fit_percent = {}
    if R.size:
        E = R / w
        for j in FIT_STATES:
            signal = data.X[..., j].reshape(-1)
            noise = sigma[j] if math.isfinite(sigma[j]) else 0.0
            if float(np.std(signal)) > EXCITATION_NOISE_FACTOR * noise:
                fit_percent[STATE_NAMES[j]] = _fit_percent(E[..., j].reshape(-1), signal)
    quality["fit_percent"] = fit_percent
    poor = {k: v for k, v in fit_percent.items() if v < POOR_FIT_PERCENT}
    if poor:
        text = ", ".join(f"{k} {v:.0f} %" for k, v in poor.items())
        warnings.append(
            f"poor fit: the model explains little of the measured {text} (fit percent over the "
            f"window steps, below {POOR_FIT_PERCENT:g} %); the log and the model disagree"
        )

    quality["influential_windows"] = _influence(theta, std, R, J, data, options, params, warnings)
    return quality, warnings


def _influence(theta, std, R, J, data, options, params, warnings) -> list[dict]:
    free = options.free_index
    if R.size == 0 or not (np.all(np.isfinite(R)) and np.all(np.isfinite(J))):
        return []
    Jf = J.reshape(data.n_windows, -1, NTHETA)[:, :, free]
    r = R.reshape(data.n_windows, -1)
    g = np.einsum("bnp,bn->bp", Jf, r)  # each window's gradient contribution
    _, precision = options.prior(params)
    info = np.einsum("bnp,bnq->pq", Jf, Jf) + np.diag(precision[free])
    try:
        shift = np.linalg.solve(info, g.T).T  # (B, p): leave-one-out shift, one GN step
    except np.linalg.LinAlgError:
        return []
    s = np.where(np.isfinite(std[free]), std[free], np.inf)
    limit = np.maximum(INFLUENCE_STD * s, INFLUENCE_REL * np.abs(theta[free]))
    excess = np.max(np.abs(shift) / limit, axis=1)
    flagged = np.flatnonzero(excess > 1.0)
    if flagged.size == 0:
        return []
    order = flagged[np.argsort(-excess[flagged])]
    names = [THETA_NAMES[i] for i in free]
    listed = [
        {
            "start_row": int(data.start[b]),
            "t0_s": float(data.t0[b]),
            "shift": {n: float(v) for n, v in zip(names, shift[b], strict=True)},
        }
        for b in order[:MAX_LISTED_WINDOWS]
    ]
    top = order[0]
    k = int(np.argmax(np.abs(shift[top]) / limit))
    together = shift[flagged].sum(axis=0)
    warnings.append(
        f"single samples dominate: leaving out any one of {flagged.size} of the "
        f"{data.n_windows} windows moves {'/'.join(names)} by more than {INFLUENCE_STD:g} std "
        f"and {INFLUENCE_REL:.0%}; leaving out the worst (from t = {data.t0[top]:.4g} s, row "
        f"{data.start[top]}) moves {names[k]} by {shift[top, k]:+.3g}, all of them "
        f"{together[k]:+.3g}; check the log there (a corrupt sample?) or drop those rows"
    )
    return listed


# --- is a friction peak shown by the data? ---------------------------------------------------

PEAK_SHOWN_CHI2 = 3.84
"""A fitted peak counts as shown when its quasi-likelihood ratio against a tyre without a peak
reaches the chi-square 95 % quantile of one degree of freedom (the handing's 95 %)."""
NO_PEAK_FACTOR = 1000.0
"""The tyre "without a peak" is the fitted tyre with its peak this many times the fitted one,
at the fitted small-slip stiffness: over any data a car can drive it is the linear tyre."""


def no_peak_theta(model, theta: np.ndarray) -> np.ndarray:
    """``theta`` (mu first) with the peak ``NO_PEAK_FACTOR`` times higher and the same
    small-slip stiffness: ``peak_tyre``'s stiffness ``mu_nom (mu / mu_nom)^k_s`` kept by
    changing ``k_s`` with it."""
    theta = np.asarray(theta, dtype=float)
    flat = theta.copy()
    mu = float(theta[0])
    flat[0] = mu * NO_PEAK_FACTOR
    names = list(model.param_names)
    if "peak_tyre.k_s" in names:
        k = names.index("peak_tyre.k_s")
        log_nom = math.log(float(model.vehicle.mu))
        flat[k] = theta[k] * (math.log(mu) - log_nom) / (math.log(flat[0]) - log_nom)
    return flat


def peak_evidence(model, theta: np.ndarray, data, starts, horizon: int, burn_in: int, overlap):
    """How strongly the data reject a tyre without a peak, against the fitted peak: the
    quasi-likelihood ratio ``(cost_no_peak - cost_fit) n_eff / cost_fit``.

    ``model`` the workbench model at ``theta`` (mu first; a ``peak_tyre``), fitted on ``data``'s
    windows ``starts`` (``horizon`` steps, ``burn_in`` left out of the cost, as the fit's
    cost); ``overlap`` the windows' overlap (horizon over stride). ``n_eff`` is the fitter's
    count of independent residuals (windows over the overlap, times the fitted states), so
    ``cost_fit / n_eff`` is the variance of one independent residual, model error included:
    the ratio is the cost difference in the units chance gives it, a chi-square with one degree
    of freedom where no peak is the truth. NaN where it cannot be formed.

    Why: with a tyre whose stiffness does not follow the friction (``k_s`` 0) the linear range
    says nothing about the peak, and data driven far below it are explained by any peak above
    the friction they used. A model error in the most cornering window (the car turning less
    than the model says) is then explained best by a peak just above that window's friction:
    the fit settles there with a small std (the cost rises steeply below it) and looks near
    its limit by construction, yet the data as a whole barely prefer it to no peak at all.
    Data driven at the limit prefer their peak by orders of magnitude more."""
    from pcvfe_drake.models.estimate import FIT_STATES, training_costs

    theta = np.asarray(theta, dtype=float)
    n = len(starts)
    if n < 1 or not (math.isfinite(theta[0]) and theta[0] > 0):
        return math.nan
    rows = np.stack([theta, no_peak_theta(model, theta)])
    cost = training_costs(model, rows, data, np.asarray(starts), horizon, burn_in)
    n_eff = n / max(float(overlap), 1.0) * len(FIT_STATES)
    if not (all(math.isfinite(c) for c in cost) and cost[0] > 0):
        return math.nan
    return float((cost[1] - cost[0]) * n_eff / cost[0])


def peak_not_shown(fitter, result) -> str:
    """Why the effect fit ``result`` of ``fitter`` (an ``EffectFitter`` with a peak tyre) does
    not show its friction peak on the windows it was fitted on (``result.windows``; "": it
    does; see :func:`peak_evidence`)."""
    data, starts, horizon, burn_in = result.windows
    overlap = fitter.horizon_s / fitter.stride_s
    ratio = peak_evidence(fitter.model, result.model_theta, data, starts, horizon, burn_in, overlap)
    if math.isfinite(ratio) and ratio >= PEAK_SHOWN_CHI2:
        return ""
    return (
        f"the data do not show the peak: a tyre without one explains them nearly as well "
        f"(quasi-likelihood ratio {ratio:.3g} < {PEAK_SHOWN_CHI2:g})"
    )
