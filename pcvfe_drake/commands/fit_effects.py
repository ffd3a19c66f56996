"""``pcvfe fit --effects``: the live fitter's effect model fitted on a whole log the way ``pcvfe
diagnose --add`` fits it. It composes the workbench (its windows, start and solver) with the
estimator's reading of a fit (controller theta, friction used, identifiability), so it lives
above both."""

from __future__ import annotations

import math

from pcvfe_drake.estimation.effect_fit import controller_theta, friction_is_peak, identifiability
from pcvfe_drake.estimation.estimate_table import Z95
from pcvfe_drake.estimation.fit_options import COVARIANCES, HAC_LAG_S, with_model_error
from pcvfe_drake.estimation.probe import wheel_peak_share
from pcvfe_drake.models.effect_model import parse_effects
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.workbench.ranking import Workbench


def fit_log(
    data,
    vehicle: VehicleParams,
    effects,
    identifiable_std: float = 0.05,
    near_limit_fraction: float = 0.6,
    covariance: str = "hac",
    hac_lag_s: float = HAC_LAG_S,
    model_error_rel: float = 0.0,
) -> dict:
    """``pcvfe fit --effects``: the effect model fitted on a whole log as ``pcvfe diagnose
    --add`` fits it (one model, mu per context, the effect parameters shared; the diagnosis's
    training windows, start and solver), so both give the same parameters on the same data.

    Returns a JSON-ready dict: ``effects``, ``params`` (every parameter: value, std, unit, ...),
    ``mu_is_peak``, and per context the controller's theta, mu's std (``covariance``: ``hac``,
    the Newey-West sandwich over the time-ordered training windows, or ``iid``, the workbench's;
    with the model-error budget ``model_error_rel``),
    its lower bound from the friction used, ``near_limit``, ``identifiable``, ``below_used``
    (judged as the live estimator judges them: :func:`identifiability` on the std the data
    leave, with the wheels' ``wheel_peak_share`` when the model has the track) and the 95 %
    interval ``mu_interval_95`` (as ``ContextEstimate.mu_interval_95``; None: no upper bound).
    """
    wb = Workbench(data, vehicle)
    specs = parse_effects(effects)
    model = wb.base_model.with_effects(*[sp.name for sp in specs])
    fixed = {f"{sp.name}.{k}": v for sp in specs for k, v in sp.fixed.items()}
    lag = None
    if covariance == "hac":  # training windows: h_fit steps, one every h_fit steps
        span = wb.h_fit * data.dt
        lag = max(1, math.ceil((span + hac_lag_s) / span - 1e-9))
    elif covariance != "iid":
        raise ValueError(f"covariance must be one of {COVARIANCES}, got {covariance!r}")
    res = wb.fit_model(model, warm=wb.baseline, fixed=fixed, hac_lag=lag)
    peak = friction_is_peak(model)
    track = dict(zip(model.param_names, res.theta, strict=True)).get("track_slip.t", 0.0)
    contexts = {}
    for c, label in enumerate(data.context_names):
        theta = controller_theta(model, res.theta, c)
        mu_idx = next(i for i, p in enumerate(model.params) if p.effect is None and p.context == c)
        rows = data.context == c
        share = math.nan  # as the live estimator: with the track, how near each wheel came
        if peak and track > 0:
            share = wheel_peak_share(
                data.t[rows], data.x[rows], vehicle, theta[0], theta[0] * theta[1:], track
            )
        # the live estimator's judgement (identifiability), on the std the data leave
        judged = identifiability(
            data.t[rows],
            data.x[rows],
            theta[0],
            float(res.std[mu_idx]),
            peak,
            math.nan,
            near_limit_fraction,
            identifiable_std,
            share,
        )
        used, near = judged["mu_lower_bound"], judged["near_limit"]
        std = with_model_error(theta[0], float(res.std[mu_idx]), model_error_rel)
        if near or not math.isfinite(used):  # the data came near the limit: two-sided
            interval = [theta[0] - Z95 * std, theta[0] + Z95 * std]
        else:  # never near: the friction used bounds mu from below, nothing from above
            interval = [used, None]
        contexts[label] = {
            "theta": dict(zip(("mu", "C_Sf", "C_Sr"), map(float, theta), strict=True)),
            "mu_std": std,
            **judged,
            "wheel_peak_share": share,
            "mu_interval_95": interval,
        }
    return {
        "effects": [{"name": s.name, "fixed": s.fixed} for s in parse_effects(effects)],
        "params": res.params_dict(),
        "mu_is_peak": friction_is_peak(model),
        "train_cost": float(res.cost),
        "iterations": int(res.n_iter),
        "converged": bool(res.converged),
        "training_windows": int(wb.train_starts.size),
        "covariance": covariance,
        "model_error_rel": model_error_rel,
        "contexts": contexts,
    }
