"""The run summary never passes a prior off as an estimate: a context with no fit says so and
shows what the car was handed."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from pcvfe_drake.runs.summary import entry_fitted, summarize_run, summary_table

PRIOR_MU = 1.0489


def short_run() -> pd.DataFrame:
    """5 s at 5 m/s: 2 s on concrete (context 0, fitted 0.61), 3 s on sand (context 1, never
    fitted: the car was handed the 0.3 floor)."""
    t = np.arange(0.0, 5.0, 0.05)
    on_sand = t >= 2.0
    return pd.DataFrame(
        {
            "t": t,
            "sx": 5.0 * t,
            "sy": np.zeros_like(t),
            "v": np.full_like(t, 5.0),
            "delta": np.zeros_like(t),
            "psi": np.zeros_like(t),
            "psi_dot": np.zeros_like(t),
            "beta": np.zeros_like(t),
            "steer_rate": np.zeros_like(t),
            "accel": np.zeros_like(t),
            "terrain": np.where(on_sand, "sand", "concrete"),
            "mu_true": np.where(on_sand, 0.45, 0.6),
            "context": np.where(on_sand, 1, 0),
            "mu_hat": np.where(on_sand, 0.3, 0.61),
        }
    )


def table(status_sand: str = "too_little_data") -> list[dict]:
    nan = float("nan")
    return [
        {"id": 0, "mu": 0.61, "mu_std": 0.01, "samples": 40, "status": "fitted"},
        {"id": 1, "mu": PRIOR_MU, "mu_std": nan, "samples": 60, "status": status_sand},
    ]


def summarize(estimates: list[dict]) -> dict:
    return summarize_run(
        short_run(),
        scenario="short",
        wall_time_s=1.0,
        terrain_mu={"concrete": 0.6, "sand": 0.45},
        estimate_table=estimates,
    )


def test_context_without_fit_has_no_mu_hat_and_shows_the_handed_mu():
    s = summarize(table())
    by_id = {e["id"]: e for e in s["mu_estimates"]}
    sand, concrete = by_id[1], by_id[0]
    assert sand["fitted"] is False
    assert sand["mu_hat"] is None and sand["abs_error"] is None and sand["std"] is None
    assert sand["interval_95"] is None and sand["covered_95"] is None
    assert sand["handed_mu"] == 0.3 and sand["prior_mu"] == PRIOR_MU
    assert concrete["fitted"] is True and concrete["mu_hat"] == 0.61
    assert abs(concrete["abs_error"] - 0.01) < 1e-12 and concrete["handed_mu"] == 0.61
    json.dumps(s, allow_nan=False)
    text = summary_table(s)
    row = next(line for line in text.splitlines() if line.split()[:2] == ["1", "sand"])
    assert "no fit" in row and "1.049" not in row and "0.599" not in row
    assert row.split()[3:6] == ["no", "fit", "0.300"]  # mu_hat "no fit", handed 0.300
    header = next(line for line in text.splitlines() if line.startswith("context  terrain"))
    assert "handed" in header


def test_which_entries_hold_a_fit():
    assert not entry_fitted({"status": "prior"})
    assert not entry_fitted({"status": "too_little_data"})
    assert not entry_fitted({"status": "diverged", "first_fit_s": float("nan")})
    assert entry_fitted({"status": "diverged", "first_fit_s": 3.0})  # the last good estimate
    assert entry_fitted({"status": "fitting"}) and entry_fitted({})
    assert summarize(table("prior"))["mu_estimates"][1]["fitted"] is False
