"""What a friction fit answers: the friction with its std, or a lower bound marked "not
identifiable".

A solver converges on any data. Its mu is the friction only where the data came near the
limit, determine it (a small std), lie at or below it, and are explained by the model; else the
only answer the data give is a lower bound, the lateral friction the car used. The judgement is
the live estimator's (``effect_fit.identifiability`` for a friction peak, and the fit-quality
checks of ``fit_quality``), so that ``pcvfe fit`` and the estimator answer alike.
"""

from __future__ import annotations

import math

from pcvfe_drake.estimation.fit_quality import LOSS_NOISE_RATIO_WARN, POOR_FIT_PERCENT


def mu_headline(
    mu: float, std: float, judged: dict, fitted: bool = True, limit: float = math.nan
) -> dict:
    """A context's answer: ``{"kind": "estimate", "mu", "std"}`` where mu is identifiable, else
    ``{"kind": "lower_bound", "mu_at_least", "reason"}``: the friction the data used, which the
    car had at least (the converged fit is not a friction there); ``{"kind": "no_fit"}`` where
    nothing was fitted (``fitted`` False: too little data; mu is the prior). Each has ``text``.
    ``limit``: the identifiable std, judged on ``judged["mu_std_data"]`` (the std the data
    leave, without the model-error budget) where given, else ``std``."""
    bound = judged["mu_lower_bound"]
    at_least = f"mu >= {bound:.3f}" if math.isfinite(bound) else "no bound"
    if not fitted:
        return {
            "kind": "no_fit",
            "mu_at_least": bound if math.isfinite(bound) else None,
            "reason": "no std: too little data, or mu on its bound (the data do not determine it)",
            "text": f"no fit ({at_least})",
        }
    if judged["identifiable"]:
        return {"kind": "estimate", "mu": mu, "std": std, "text": f"{mu:.3f} +- {std:.2g}"}
    if judged.get("distrust"):
        reason = f"the fit is not trustworthy ({judged['distrust']}; fit {mu:.3g})"
    elif judged.get("below_used"):
        reason = f"the fit {mu:.3g} is below the friction the data used: not a friction"
    elif not judged["near_limit"]:
        reason = f"the data never came near the limit (used {_fmt(bound, 3)}, fit {mu:.3g})"
    else:
        data_std = judged.get("mu_std_data", std)
        reason = f"the data leave a std of {_fmt(data_std, 2)}, above {_fmt(limit, 2)}"
    return {
        "kind": "lower_bound",
        "mu_at_least": bound if math.isfinite(bound) else None,
        "reason": reason,
        "text": f"{at_least}, not identifiable",
    }


def judge_friction(
    t,
    states,
    mu: float,
    data_std: float,
    near_limit_fraction: float,
    identifiable_std: float,
    share: float = math.nan,
) -> dict:
    """Whether ``mu +- data_std`` is the friction of a context's data (``t`` [s], ``states``
    (N, 7)): the live estimator's judgement of a friction peak (``effect_fit.identifiability``
    with ``peak=True``, with the estimator's ``near_limit_fraction`` and ``identifiable_std``;
    ``share``: the wheels' peak share, NaN: not judged), whatever the model. The answer states
    mu as the friction: only the lateral friction used bounds it (in the project's
    ``lateral_peak`` worlds mu is the lateral peak alone, and braking and driving use the
    longitudinal one), and a fit below that bound is impossible for a friction, whatever a
    linear tyre makes of it (its mu is a stiffness scale)."""
    from pcvfe_drake.estimation.effect_fit import identifiability

    return identifiability(
        t,
        states,
        mu,
        data_std,
        True,
        math.nan,
        near_limit_fraction,
        identifiable_std,
        share,
    )


def distrust(quality: dict) -> str | None:
    """Why the fit-quality checks (``fit_quality.assess``) say the fitted mu is not the
    friction, or None: mu on its bound, a loss far above what the noise explains, or a poor fit
    of the states friction acts on (each is a model that does not explain the data, so its mu
    is not determined by them)."""
    if "mu" in quality.get("at_bound", []):
        return "mu on its bound"
    ratio = quality.get("loss_noise_ratio", math.nan)
    if ratio is not None and ratio > LOSS_NOISE_RATIO_WARN:
        return f"the loss is {ratio:.3g} x what the noise explains: the model misses the data"
    poor = {k: v for k, v in quality.get("fit_percent", {}).items() if v < POOR_FIT_PERCENT}
    if poor:
        return "poor fit of " + ", ".join(f"{k} ({v:.0f} %)" for k, v in poor.items())
    return None


def _fmt(value: float | None, digits: int = 4) -> str:
    return f"{value:.{digits}g}" if value is not None and math.isfinite(value) else "-"
