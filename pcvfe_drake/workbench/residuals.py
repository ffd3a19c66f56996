"""See where the model fails: residual whiteness, input cross-correlation and breakdowns.

* One-step-ahead prediction residuals per state on the held-out windows, started from the raw
  measurements: autocorrelation for lags 1..25 and cross-correlation with each input for lags
  0..25 (input leading), with the 99 % band ``+-2.576 / sqrt(N)`` of a white sequence (as
  MATLAB's ``resid``). Measurement noise enters a one-step residual twice (at the start and at
  the end), which makes lag 1 negative (about -0.5 for states the model integrates) even for a
  perfect model; the whiteness verdict therefore counts lags 2..25.
* Multi-step (held-out window) whitened RMS error broken down by time block, by place on the
  map (a 3 x 3 grid over the driven area), by context, and by operating regime: speed,
  lateral acceleration ``|v psi_dot|``, longitudinal command, steering rate (bins over the
  data's own range), and accelerating / coasting / braking.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import norm

from pcvfe_drake.models.data import DriveData, window_starts
from pcvfe_drake.models.estimate import FIT_STATES
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.vehicle.single_track import INPUT_NAMES, STATE_NAMES, wrap_angle
from pcvfe_drake.workbench.evidence import (
    bartlett_ccf,
    lagged_corr,
    ma1_portmanteau,
    prewhitened_ccf,
)
from pcvfe_drake.workbench.verdict import bin_label, range_edges

MAX_LAG = 25
BAND_Z99 = 2.576


def whiteness(model: WorkbenchModel, theta: np.ndarray, data: DriveData, n_blocks: int = 6):
    """One-step residual auto- and input cross-correlations on held-out data (JSON-ready).

    Bands hold their nominal rate on a log the model explains: for lags >= 2 the band of the
    autocorrelation is Bartlett's ``2.576 sqrt((1 + 2 r_1^2) / N)`` (one-step residuals of a
    perfect model are MA(1): the noise of one sample enters two residuals). ``cross_corr`` is
    the raw cross-correlation with its Bartlett band ``cross_band_99``; ``correlated_with``
    names inputs whose raw (Bartlett) or prewhitened cross-correlation is beyond its band with
    a Bonferroni correction over both views and the lags (p < 0.01). ``white`` is the
    portmanteau test of lags 2..25 at p >= 0.01, with the null distribution of an MA(1)
    residual (:func:`~pcvfe_drake.workbench.evidence.ma1_portmanteau`: the lags of an MA(1)
    are correlated with each other, which a chi-square with 24 degrees of freedom ignores)."""
    starts = window_starts(data, 1, 1, "heldout", n_blocks)
    Z = model.simulate(theta, data, starts, 1, x0=data.x[starts])
    err = Z[:, 1, :7] - data.x[starts + 1]
    err[:, 4] = wrap_angle(err[:, 4])
    n = starts.size
    band = BAND_Z99 / np.sqrt(max(n, 1))
    out = {"n": int(n), "band_99": float(band), "states": {}}
    for i in FIT_STATES:
        name = STATE_NAMES[i]
        acf = lagged_corr(err[:, i], err[:, i], MAX_LAG)[1:]
        ccf = {
            u: lagged_corr(err[:, i], data.u[starts, j], MAX_LAG).tolist()
            for j, u in enumerate(INPUT_NAMES)
        }
        band_k = BAND_Z99 * np.sqrt((1.0 + 2.0 * acf[0] ** 2) / max(n, 1))
        _, p_white = ma1_portmanteau(acf, n)
        outside = float(np.mean(np.abs(acf[1:]) > band_k))
        cross_band, correlated = {}, []
        acf0 = np.concatenate([[1.0], acf])
        for j, u in enumerate(INPUT_NAMES):
            pw, sd = prewhitened_ccf(err[:, i], data.u[starts, j], MAX_LAG)
            raw, sd_raw = bartlett_ccf(err[:, i], data.u[starts, j], MAX_LAG, acf0)
            cross_band[u] = float(BAND_Z99 * sd_raw)
            z = max(np.max(np.abs(pw)) / sd, np.max(np.abs(raw)) / sd_raw)
            p = 2.0 * (MAX_LAG + 1) * 2.0 * norm.sf(z)
            if p < 0.01:
                correlated.append(u)
        out["states"][name] = {
            "autocorr": acf.tolist(),
            "band_99_lag2": float(band_k),
            "portmanteau_p": p_white,
            "cross_corr": ccf,
            "cross_band_99": cross_band,
            "fraction_outside_band": outside,
            "white": bool(p_white >= 0.01),
            "cross_corr_max": {u: float(np.max(np.abs(c))) for u, c in ccf.items()},
            "correlated_with": correlated,
        }
    return out


def _bins(values: np.ndarray, edges: np.ndarray, labels: list[str], score: np.ndarray):
    idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(labels) - 1)
    rows = []
    for b, label in enumerate(labels):
        sel = idx == b
        if sel.any():
            rows.append(
                {"bin": label, "n": int(sel.sum()), "rms": float(np.sqrt(np.mean(score[sel])))}
            )
    return rows


def _range_bins(values: np.ndarray, unit: str, score: np.ndarray):
    """Bins over the data's own range (see :func:`pcvfe_drake.workbench.verdict.range_edges`)."""

    edges = range_edges(values)
    labels = [bin_label(edges[i], edges[i + 1], unit) for i in range(edges.size - 1)]
    return _bins(values, edges[:-1], labels, score)


def breakdowns(err: np.ndarray, starts: np.ndarray, data: DriveData, n_time_bins: int = 6):
    """Whitened multi-step RMS error per window, grouped (JSON-ready).

    Args:
        err: errors (N, H, 7) of held-out windows starting at ``starts``.
    """
    idx = list(FIT_STATES)
    score = np.mean((err[:, :, idx] / data.sigma[idx]) ** 2, axis=(1, 2))
    mid = starts + err.shape[1] // 2
    x = data.x[mid]
    u = data.u[mid]
    t = data.t[mid]
    out = {}
    t_edges = np.linspace(data.t[0], data.t[-1], n_time_bins + 1)
    out["time"] = _bins(
        t,
        t_edges[:-1],
        [f"{t_edges[i]:.0f}-{t_edges[i + 1]:.0f} s" for i in range(n_time_bins)],
        score,
    )
    gx = np.linspace(data.x[:, 0].min(), data.x[:, 0].max(), 4)
    gy = np.linspace(data.x[:, 1].min(), data.x[:, 1].max(), 4)
    cx = np.clip(np.searchsorted(gx, x[:, 0], side="right") - 1, 0, 2)
    cy = np.clip(np.searchsorted(gy, x[:, 1], side="right") - 1, 0, 2)
    cell = cx * 3 + cy
    out["place"] = [
        {
            "bin": f"x {gx[c // 3]:.0f}..{gx[c // 3 + 1]:.0f} m, "
            f"y {gy[c % 3]:.0f}..{gy[c % 3 + 1]:.0f} m",
            "n": int((cell == c).sum()),
            "rms": float(np.sqrt(np.mean(score[cell == c]))),
        }
        for c in range(9)
        if (cell == c).any()
    ]
    ctx = data.context[starts]
    out["context"] = [
        {"bin": name, "n": int((ctx == c).sum()), "rms": float(np.sqrt(np.mean(score[ctx == c])))}
        for c, name in enumerate(data.context_names)
        if (ctx == c).any()
    ]
    out["speed"] = _range_bins(x[:, 3], "m/s", score)
    out["lateral_accel"] = _range_bins(np.abs(x[:, 3] * x[:, 5]), "m/s^2", score)
    out["accel_command"] = _range_bins(u[:, 1], "m/s^2", score)
    out["steering_rate"] = _range_bins(np.abs(u[:, 0]), "rad/s", score)
    mode = np.where(u[:, 1] > 0.1, 0, np.where(u[:, 1] < -0.1, 2, 1))
    out["drive_mode"] = [
        {
            "bin": label,
            "n": int((mode == m).sum()),
            "rms": float(np.sqrt(np.mean(score[mode == m]))),
        }
        for m, label in enumerate(("accelerating", "coasting", "braking"))
        if (mode == m).any()
    ]
    return out
