"""Statistical evidence for the workbench's claims: error drops, the noise floor, leftovers.

* :func:`paired_drop_test`: is model B's held-out error really lower than model A's? A paired
  comparison of the per-window whitened MSEs on the same held-out windows. Windows overlap
  (2 s long every 0.25 s), so the windows are grouped into runs of ``horizon / stride``
  consecutive windows and the standard error is that of the group means.
* :func:`excess_error_test`: is the held-out multi-step error above what measurement noise
  explains? The per-window excess (whitened MSE minus the window's noise floor) is tested
  against zero with the grouped standard error a perfect model would show (simulated), plus
  the uncertainty of the noise floor itself (the noise scales are estimated from the log: a
  relative standard error of about ``sqrt(2.7 / n)`` each for the median-absolute-deviation
  estimate from ``n`` samples).
* :func:`residual_structure`: is anything predictable left in the residuals? Residuals of
  predictions over ``RESID_STEP_S`` (0.2 s) from measured states on the held-out blocks, one
  per non-overlapping step, so that noise correlated over a few samples (an interpolated,
  upsampled log) does not look like structure. Per fitted state: a portmanteau test of the
  autocorrelations at lags 2..K (:func:`ma1_portmanteau`; lag 1 is skipped: consecutive
  residuals share one measured sample, an MA(1) null), and per input the
  largest cross-correlation at lags 0..K, raw against Bartlett's band
  (:func:`bartlett_ccf`; the raw input is smooth, which makes the naive band ``1/sqrt(N)``
  wrong) and after prewhitening the input (:func:`prewhitened_ccf`; sees dependence on the
  input's changes, e.g. a dead time), Bonferroni over both and over the lags.

The verdict combines all of these with a Bonferroni correction over the number of tests, so a
log the model explains is called "explained" at least ``1 - alpha`` of the time.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import toeplitz
from scipy.optimize import brentq
from scipy.signal import correlate
from scipy.stats import chi2, norm

from pcvfe_drake.models.data import DriveData, window_starts
from pcvfe_drake.models.estimate import FIT_STATES
from pcvfe_drake.vehicle.single_track import INPUT_NAMES, STATE_NAMES, wrap_angle

RESID_STEP_S = 0.2
"""Prediction step [s] of the residual-structure tests."""
RESID_MAX_LAG = 10
"""Largest lag (in steps of ``RESID_STEP_S``) of the residual-structure tests."""


def lagged_corr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """Correlation of ``a[k]`` with ``b[k - lag]`` for lags 0..max_lag (``b`` leading),
    normalised by the full-length standard deviations (as MATLAB's ``resid``)."""
    a = np.asarray(a, float) - np.mean(a)
    b = np.asarray(b, float) - np.mean(b)
    denom = float(np.sqrt((a @ a) * (b @ b)))
    n = a.size
    out = np.zeros(max_lag + 1)
    if denom <= 0 or n == 0:
        return out
    full = correlate(a, b, mode="full", method="auto")  # full[n - 1 + lag] = sum a[k+lag] b[k]
    lags = np.arange(0, min(max_lag, n - 1) + 1)
    out[lags] = full[n - 1 + lags] / denom
    return out


def weighted_chi2_sf(x: float, weights: np.ndarray) -> float:
    """P(sum_i w_i Z_i^2 > x) for independent standard normal Z_i and weights w_i > 0, by the
    Lugannani-Rice saddlepoint approximation (Kuonen 1999, Biometrika 86: within a few percent
    of the exact tail, deep tails included, where Imhof's numerical inversion loses its
    absolute accuracy below ~1e-9)."""
    w = np.asarray(weights, float)
    w = w[w > 1e-12 * max(float(np.max(w, initial=0.0)), 1e-300)]
    if w.size == 0 or not np.isfinite(x):
        return 1.0 if not np.isfinite(x) or x < 0 else 0.0
    if x <= 0:
        return 1.0
    mean, var = float(w.sum()), float(2.0 * np.sum(w**2))

    def k1(s):
        return float(np.sum(w / (1.0 - 2.0 * w * s)))

    if abs(x - mean) < 1e-3 * np.sqrt(var):
        # at the mean the saddlepoint formula is 0/0: Satterthwaite's scaled chi-square
        c = float(np.sum(w**2) / mean)
        return float(chi2.sf(x / c, mean / c))
    if x > mean:
        # K'(s) grows without bound towards s = 1 / (2 w_max)
        lo, hi = 0.0, 0.5 / float(w.max()) * (1.0 - 1e-15)
        if k1(hi) < x:
            return 0.0
    else:
        lo, hi = -1.0, 0.0
        while k1(lo) > x:
            lo *= 2.0
    s = float(brentq(lambda v: k1(v) - x, lo, hi, xtol=1e-300, rtol=1e-14, maxiter=500))
    kappa = -0.5 * float(np.sum(np.log1p(-2.0 * w * s)))
    r = float(np.sign(s) * np.sqrt(max(2.0 * (s * x - kappa), 0.0)))
    u = s * float(np.sqrt(np.sum(2.0 * w**2 / (1.0 - 2.0 * w * s) ** 2)))
    if r == 0.0 or u == 0.0:
        c = float(np.sum(w**2) / mean)
        return float(chi2.sf(x / c, mean / c))
    return float(np.clip(norm.sf(r) + norm.pdf(r) * (1.0 / u - 1.0 / r), 0.0, 1.0))


def ma1_portmanteau(acf: np.ndarray, n: int) -> tuple[float, float]:
    """Portmanteau test of autocorrelations at lags 2..K for an MA(1) null.

    ``acf``: sample autocorrelations at lags 1..K of ``n`` residuals. A residual that starts
    and ends on measured samples is MA(1) for a perfect model (one sample's noise enters two
    residuals; ``r_1`` ~ -0.5 for a state the model integrates). Under that null Bartlett's
    formula gives the lags' covariance ``N cov(r_h, r_{h+d}) = 1 + 2 r_1^2, 2 r_1, r_1^2`` for
    ``d = 0, 1, 2`` (0 beyond): adjacent lags are strongly *correlated* (-0.67 at r_1 = -0.5).
    The statistic ``Q = N sum r_h^2 / (1 + 2 r_1^2)`` is therefore not chi-square with K - 1
    degrees of freedom (that treats the lags as independent; at r_1 = -0.5 it makes a p-value
    of 3.3e-4 about 12x too small, measured by simulation) but a weighted sum of chi-square(1)
    variables with the eigenvalues of that covariance as weights; its tail is
    :func:`weighted_chi2_sf`. Returns (Q, p)."""
    acf = np.asarray(acf, float)
    m = acf.size - 1
    if m < 1 or n <= 0:
        return 0.0, 1.0
    r1 = float(np.clip(acf[0], -0.5, 0.5))  # an MA(1)'s lag-1 autocorrelation is within +-0.5
    var = 1.0 + 2.0 * r1**2
    q = n * float(np.sum(acf[1:] ** 2)) / var
    col = np.zeros(m)
    col[0] = var
    if m > 1:
        col[1] = 2.0 * r1
    if m > 2:
        col[2] = r1**2
    weights = np.linalg.eigvalsh(toeplitz(col)) / var
    return q, weighted_chi2_sf(q, weights)


PREWHITEN_ORDER = 3
"""Order of the autoregressive filter that prewhitens an input before cross-correlation."""


def prewhitened_ccf(r: np.ndarray, u: np.ndarray, max_lag: int, order: int = PREWHITEN_ORDER):
    """Cross-correlation of residual ``r`` with input ``u`` at lags 0..max_lag (``u``
    leading) after prewhitening (Box-Jenkins): an AR(``order``) model of ``u`` is fitted by
    least squares and both series are passed through its inverse filter. The filtered input
    is white, so when ``r`` does not depend on ``u`` every lag has variance ~1/N whatever the
    residual's own correlation; a smooth or step-like input no longer spreads one lag's
    dependence over all lags. Returns (ccf, standard deviation under independence)."""
    u = np.asarray(u, float) - np.mean(u)
    r = np.asarray(r, float) - np.mean(r)
    n = u.size
    if n <= 4 * order + max_lag or float(u @ u) <= 0:
        return np.zeros(max_lag + 1), 1.0 / np.sqrt(max(n, 1))
    X = np.stack([u[order - i - 1 : n - i - 1] for i in range(order)], axis=1)
    phi, *_ = np.linalg.lstsq(X, u[order:], rcond=None)
    kernel = np.concatenate([[1.0], -phi])
    uf = np.convolve(u, kernel, mode="valid")
    rf = np.convolve(r, kernel, mode="valid")
    return lagged_corr(rf, uf, max_lag), 1.0 / np.sqrt(uf.size)


def bartlett_ccf(r: np.ndarray, u: np.ndarray, max_lag: int, acf_r: np.ndarray | None = None):
    """Raw cross-correlation of ``r`` with ``u`` at lags 0..max_lag and its standard deviation
    under independence by Bartlett's formula ``sqrt(sum_j rho_rr(j) rho_uu(j) / N)`` (lags
    -max_lag..max_lag; a smooth input and a correlated residual widen it). ``acf_r``: the
    residual's autocorrelation at lags 0..max_lag if already computed."""
    n = np.size(r)
    acf_r = lagged_corr(r, r, max_lag) if acf_r is None else acf_r
    acf_u = lagged_corr(u, u, max_lag)
    var = (1.0 + 2.0 * float(np.sum(acf_r[1:] * acf_u[1:]))) / max(n, 1)
    return lagged_corr(r, u, max_lag), float(np.sqrt(max(var, 0.25 / max(n, 1))))


def grouped_mean_se(values: np.ndarray, group: int) -> tuple[float, float, int]:
    """Mean, standard error and number of groups of ``values`` taken in runs of ``group``
    consecutive entries (for overlapping, hence correlated, windows)."""
    values = np.asarray(values, float)
    group = max(1, int(group))
    n_groups = values.size // group
    if n_groups < 2:
        se = float(np.std(values) / np.sqrt(max(values.size, 1))) if values.size > 1 else np.inf
        return float(np.mean(values)) if values.size else 0.0, se, max(values.size, 1)
    g = values[: n_groups * group].reshape(n_groups, group).mean(axis=1)
    return float(values.mean()), float(g.std(ddof=1) / np.sqrt(n_groups)), n_groups


def error_drop(before: dict, after: dict) -> float:
    """Fraction of the held-out model error (noise-corrected multi-step error) removed.

    Both errors are corrected with the *smaller* of the two models' noise floors, so a model
    cannot gain by amplifying the initial-state noise (a larger floor of its own)."""
    floor2 = min(before["noise_floor"], after["noise_floor"]) ** 2
    e0 = np.sqrt(max(before["multistep_error"] ** 2 - floor2, 0.0))
    e1 = np.sqrt(max(after["multistep_error"] ** 2 - floor2, 0.0))
    return float((e0 - e1) / e0) if e0 > 0 else 0.0


def paired_drop_test(before: dict, after: dict, group: int) -> dict:
    """Is the held-out error of ``after`` lower than that of ``before`` (same windows)?

    Returns mean whitened-MSE difference, its standard error and a one-sided p-value."""
    d = np.asarray(before["_mse_w"]) - np.asarray(after["_mse_w"])
    mean, se, n_groups = grouped_mean_se(d, group)
    z = mean / se if se > 0 and np.isfinite(se) else (np.inf if mean > 0 else 0.0)
    return {"mse_decrease": mean, "se": se, "groups": n_groups, "p_value": float(norm.sf(z))}


def sigma_rel_se(n_samples: int) -> float:
    """Relative standard error of one noise scale estimated from ``n_samples`` samples."""
    return float(np.sqrt(2.7 / max(n_samples, 10)))


def excess_error_test(ev: dict, data: DriveData, group: int, z_crit: float = 2.576) -> dict:
    """Held-out whitened multi-step MSE in excess of the noise floor, with its uncertainty.

    Returns ``excess`` (whitened MSE above the floor), ``se`` (windows and noise-scale
    estimate), ``p_value`` (one-sided, H0: no excess), the model error and the smallest model
    error this log could detect (``detection_limit``, 2.58 standard errors, in the units of
    ``model_error``, at the one-sided critical value ``z_crit``).

    The standard error is the one *under the null hypothesis* (simulated noise through the
    fitted model, grouped like the windows) plus the noise-scale uncertainty: a large model
    error makes the windows' own spread large, which would otherwise hide it.
    ``se_windows`` (the observed spread) is reported beside it."""
    excess_w = np.asarray(ev["_mse_w"]) - np.asarray(ev["_floor_w"])
    mean, se_win, n_groups = grouped_mean_se(excess_w, group)
    # the spread a perfect model would show (simulated noise), grouped the same way
    null_w = np.asarray(ev["_null_w"]) - np.asarray(ev["_floor_w"])
    _, se_null, _ = grouped_mean_se(null_w, group)
    floor_mse = float(np.mean(ev["_floor_w"]))
    # one noise scale per fitted state; the whitened MSE scales with 1 / sigma^2
    se_sigma = floor_mse * 2.0 * sigma_rel_se(data.n) / np.sqrt(len(FIT_STATES))
    se = float(np.hypot(se_null, se_sigma))
    z = mean / se if se > 0 else np.inf
    return {
        "excess_mse": mean,
        "se": se,
        "se_windows": se_win,
        "se_null": se_null,
        "se_noise_scale": se_sigma,
        "groups": n_groups,
        "p_value": float(norm.sf(z)),
        "model_error": float(np.sqrt(max(mean, 0.0))),
        "noise_floor": float(np.sqrt(floor_mse)),
        "detection_limit": float(np.sqrt(z_crit * se)),
    }


def step_residuals(model, theta, data: DriveData, n_blocks: int, step_s: float = RESID_STEP_S):
    """Residuals (measured minus predicted, (N, 7)) of predictions over ``step_s`` from the raw
    measured states on held-out blocks, one per non-overlapping step, with the mean inputs
    over each step (N, 2) and the start samples."""
    k = max(1, int(round(step_s / data.dt)))
    starts = window_starts(data, k, k, "heldout", n_blocks)
    if starts.size < 10:
        return np.zeros((0, 7)), np.zeros((0, 2)), starts
    Z = model.simulate(theta, data, starts, k, x0=data.x[starts])
    err = data.x[starts + k] - Z[:, k, :7]
    err[:, 4] = wrap_angle(err[:, 4])
    idx = starts[:, None] + np.arange(k)[None, :]
    return err, data.u[idx].mean(axis=1), starts


def residual_structure(
    model, theta, data: DriveData, n_blocks: int, max_lag: int = RESID_MAX_LAG
) -> dict:
    """Portmanteau whiteness and input cross-correlation tests per fitted state (see module
    docstring); JSON-ready, with one p-value per test."""
    err, u, starts = step_residuals(model, theta, data, n_blocks)
    n = err.shape[0]
    out = {"n": int(n), "step_s": RESID_STEP_S, "max_lag": max_lag, "tests": []}
    if n < 3 * max_lag:
        return out
    ctx = data.context[starts]
    out["context_bias"] = {}
    for c, label in enumerate(data.context_names):
        sel = ctx == c
        if sel.sum() < 5:
            continue
        out["context_bias"][label] = {
            STATE_NAMES[i]: {
                "bias": float(np.mean(err[sel, i]) / data.sigma[i]),
                "se": float(np.std(err[sel, i]) / data.sigma[i] / np.sqrt(sel.sum())),
            }
            for i in FIT_STATES
        }
    for i in FIT_STATES:
        name = STATE_NAMES[i]
        r = err[:, i]
        acf = lagged_corr(r, r, max_lag)
        r1 = acf[1]
        q, p_white = ma1_portmanteau(acf[1:], n)
        out["tests"].append(
            {
                "state": name,
                "kind": "autocorrelation",
                "statistic": q,
                "p_value": p_white,
                "autocorr": acf[1:].tolist(),
                "bias": float(np.mean(r)),
                "bias_se": float(np.std(r) / np.sqrt(n) * np.sqrt(max(1.0 + 2.0 * r1, 0.2))),
            }
        )
        for j, uname in enumerate(INPUT_NAMES):
            ccf, sd = prewhitened_ccf(r, u[:, j], max_lag)
            z = np.abs(ccf) / sd
            raw, sd_raw = bartlett_ccf(r, u[:, j], max_lag, acf)
            z_raw = np.abs(raw) / sd_raw
            # two views (raw with Bartlett's band: smooth dependence; prewhitened: dependence
            # on changes of the input), Bonferroni over both and over the lags
            p = float(min(1.0, 2.0 * (max_lag + 1) * 2.0 * norm.sf(max(np.max(z), np.max(z_raw)))))
            out["tests"].append(
                {
                    "state": name,
                    "kind": f"cross_correlation_{uname}",
                    "input": uname,
                    "statistic": float(np.max(z)),
                    "lag": int(np.argmax(z)),
                    "p_value": p,
                    "cross_corr": ccf.tolist(),
                    "band_99": float(2.576 * sd),
                }
            )
    return out
