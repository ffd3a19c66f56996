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
from pcvfe_drake.models.data import EXCITATION_NOISE_FACTOR
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
    return 1.4826 * mad / math.sqrt(70.0)


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
