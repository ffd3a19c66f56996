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
from dataclasses import dataclass

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
    theta = np.asarray(theta, dtype=float)
    starts = np.asarray(starts)
    if starts.size < 1 or not (math.isfinite(theta[0]) and theta[0] > 0):
        return math.nan
    cost_fit, cost_no_peak, _ = _both_tyres(model, theta, data, starts, horizon, burn_in)
    return evidence_ratio(cost_fit, cost_no_peak, starts.size, overlap)


def evidence_ratio(cost_fit: float, cost_no_peak: float, n_windows: int, overlap) -> float:
    """:func:`peak_evidence`'s ratio from the two whitened costs over ``n_windows`` windows
    overlapping ``overlap`` times; NaN where a cost is not finite or the fit's is not > 0."""
    n_eff = n_windows / max(float(overlap), 1.0) * len(_fit_states())
    if not (math.isfinite(cost_fit) and math.isfinite(cost_no_peak) and cost_fit > 0):
        return math.nan
    return float((cost_no_peak - cost_fit) * n_eff / cost_fit)


def _fit_states():
    from pcvfe_drake.models.estimate import FIT_STATES

    return FIT_STATES


def _both_tyres(model, theta, data, starts, horizon, burn_in):
    """The fitted tyre's and the tyre without a peak's whitened costs over the windows, from one
    batched rollout (``models.estimate.training_costs``'s sums), and the no-peak tyre's squared
    errors per window and fit state, unwhitened (W, S)."""
    from pcvfe_drake.models.estimate import whitened_errors

    n = starts.size
    rows = np.stack([theta, no_peak_theta(model, theta)])
    e = whitened_errors(
        model, np.repeat(rows, n, axis=0), data, np.tile(starts, 2), horizon, burn_in
    )
    flat = e.reshape(2, -1)
    costs = [float(r @ r) for r in flat]
    return costs[0], costs[1], _unwhitened_sums(e[n:], data)


def _unwhitened_sums(e: np.ndarray, data) -> np.ndarray:
    """Per window and fit state the sum over steps of the squared errors [state units^2] from
    whitened errors ``e`` (W, steps, S)."""
    sigma = data.sigma[list(_fit_states())]
    return np.einsum("wks,wks->ws", e, e) * sigma**2


@dataclass(frozen=True)
class NoPeakSums:
    """The tyre without a peak on a context's windows, kept between refits (the peak evidence
    of an incremental refit; immutable, so the estimator's copies share it).

    Attributes:
        keys: window start times on the sample clock (``EffectFitter``'s window keys) (W,).
        points: the fitted parameters each window was rolled out at (W, F).
        ee: the no-peak tyre's squared errors per window and fit state, summed over the
            window's steps, unwhitened [state units^2] (W, S).
    """

    keys: np.ndarray
    points: np.ndarray
    ee: np.ndarray


def peak_not_shown(fitter, result) -> str:
    """Why the effect fit ``result`` of ``fitter`` (an ``EffectFitter`` with a peak tyre) does
    not show its friction peak on the windows it was fitted on (``result.windows``; "": it
    does; see :func:`peak_evidence`): both tyres rolled out on every window."""
    data, starts, horizon, burn_in = result.windows
    overlap = fitter.horizon_s / fitter.stride_s
    ratio = peak_evidence(fitter.model, result.model_theta, data, starts, horizon, burn_in, overlap)
    return _not_shown(ratio)


def peak_check(fitter, result, kept: NoPeakSums | None):
    """:func:`peak_not_shown` as the live estimator forms it: ``(reason, sums)``, ``kept`` the
    last call's sums for this context (None: none, or forgotten with the refit's windows);
    the ratio from :func:`kept_peak_evidence`."""
    ratio, sums = kept_peak_evidence(fitter, result, kept)
    return _not_shown(ratio), sums


def kept_peak_evidence(fitter, result, kept: NoPeakSums | None):
    """:func:`peak_evidence` of the fit ``result`` on its windows, ``(ratio, sums)``.

    For an incremental refit (``result.incremental``) it does only new work, as the refit
    does: the fitted tyre's cost is the refit's own (its windows' quadratic models at the
    estimate, ``result.ssr``), and the tyre without a peak is rolled out only on the windows
    that are new or whose point lies more than ``incremental_fit.RELINEARISE_SCALE`` of a
    parameter's typical magnitude from the estimate (the rule the refit relinearises by);
    windows that left the fit are dropped. After a batch fit both tyres are rolled out on
    every window (:func:`peak_evidence`'s ratio), which seeds the sums."""
    data, starts, horizon, burn_in = result.windows
    overlap = fitter.horizon_s / fitter.stride_s
    theta = np.asarray(result.model_theta, dtype=float)
    if np.size(starts) < 1 or not (math.isfinite(theta[0]) and theta[0] > 0):
        return math.nan, None
    if result.incremental and math.isfinite(result.ssr):
        cost_no_peak, sums = _no_peak_incremental(fitter, theta, result.windows, kept)
        return evidence_ratio(result.ssr, cost_no_peak, starts.size, overlap), sums
    cost_fit, cost_no_peak, ee = _both_tyres(fitter.model, theta, data, starts, horizon, burn_in)
    points = np.tile(theta[~fitter.fixed], (starts.size, 1))
    sums = NoPeakSums(fitter._window_keys(data, starts), points, ee)
    return evidence_ratio(cost_fit, cost_no_peak, starts.size, overlap), sums


def _not_shown(ratio: float) -> str:
    if math.isfinite(ratio) and ratio >= PEAK_SHOWN_CHI2:
        return ""
    return (
        f"the data do not show the peak: a tyre without one explains them nearly as well "
        f"(quasi-likelihood ratio {ratio:.3g} < {PEAK_SHOWN_CHI2:g})"
    )


def _no_peak_incremental(fitter, theta, windows, kept: NoPeakSums | None):
    """The no-peak tyre's whitened cost over ``windows`` at ``theta``, rolling out only the
    windows ``kept`` does not hold near ``theta``; with the new sums."""
    from pcvfe_drake.estimation.incremental_fit import far_from, stored_rows
    from pcvfe_drake.models.estimate import whitened_errors

    data, starts, horizon, burn_in = windows
    model, free = fitter.model, ~fitter.fixed
    keys = fitter._window_keys(data, starts)
    point = theta[free]
    points = np.tile(point, (keys.size, 1))
    ee = np.zeros((keys.size, len(_fit_states())))
    stale = np.ones(keys.size, dtype=bool)
    if kept is not None and kept.keys.size:
        where = stored_rows(kept.keys, keys)
        have = where >= 0
        near = np.zeros(keys.size, dtype=bool)
        near[have] = ~far_from(kept.points[where[have]], point, model.scales()[free])
        points[near], ee[near] = kept.points[where[near]], kept.ee[where[near]]
        stale = ~near
    rows = np.flatnonzero(stale)
    if rows.size:
        flat = np.tile(no_peak_theta(model, theta), (rows.size, 1))
        e = whitened_errors(model, flat, data, starts[rows], horizon, burn_in)
        ee[rows] = _unwhitened_sums(e, data)
    sigma = data.sigma[list(_fit_states())]
    return float(np.sum(ee / sigma**2)), NoPeakSums(keys, points, ee)
