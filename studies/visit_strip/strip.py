"""A strip of another friction, called noise by the camera, inside a context's visit: what the
visit rule (``sample_store.visit_members``) does to the context's fit.

A 12 s S-curve drive of the Ford's single-track model on the context's friction, with a strip of
another friction planted at 4.8 s (in the second bend) and labelled noise. The context is fitted
with the handing's hold ``noise_hold_s`` 1 s (the strip joins the visit) and 0 s (it does not).

Usage: python studies/visit_strip/strip.py
Prints one row per (context mu, strip mu, strip length): mu_hat, its std and the windows, both
holds, and whether the 95 % interval holds the context's friction.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pcvfe_drake.estimation.context_estimator import ContextEstimator
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.handing.config import HandingConfig, Prior
from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.vehicle.params import ford_escort

DURATION_S = 12.0
STRIP_AT_S = 4.8


def fit(params, mu: float, strip_mu: float, strip_s: float, hold_s: float):
    t = np.arange(round(DURATION_S / 0.01) + 1) * 0.01
    strip = (t >= STRIP_AT_S) & (t < STRIP_AT_S + strip_s)
    t, S, U = s_curve_drive(params, np.where(strip, strip_mu, mu)[None, :], duration_s=DURATION_S)
    ids = np.where(strip, -1, 4)
    cfg = LiveFitConfig(handing=HandingConfig(unknown=Prior(), noise_hold_s=hold_s))
    cfg = dataclasses.replace(cfg, horizon_steps=50, stride_steps=25, min_windows=10)
    est = ContextEstimator(params, cfg)
    for k in range(t.size):
        est.add_sample(round(float(t[k]), 6), S[0][k], U[0][k], [ids[k]])
    est.refit(DURATION_S)
    return est.table().get(4)


def main() -> None:
    params = ford_escort()
    print(
        "| mu | strip mu | strip [s] | hold 1 s: mu_hat (std) windows | in 95 % | "
        "hold 0: mu_hat (std) windows |"
    )
    print("|---|---|---|---|---|---|")
    for mu, strip_mu in [(0.3, 0.8), (0.35, 1.0), (0.8, 0.25)]:
        for strip_s in (0.1, 0.3, 0.6, 0.9):
            held, left = (fit(params, mu, strip_mu, strip_s, h) for h in (1.0, 0.0))
            inside = abs(held.mu - mu) <= 1.96 * held.theta_std[0]
            print(
                f"| {mu} | {strip_mu} | {strip_s} | {held.mu:.3f} ({held.theta_std[0]:.4f}) "
                f"{held.n_windows} | {'yes' if inside else 'NO'} | {left.mu:.3f} "
                f"({left.theta_std[0]:.4f}) {left.n_windows} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
