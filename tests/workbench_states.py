"""Shared inputs of the effect tests that compare the workbench's equations with the separately
written truth (``synth._truth_rates``): random states, the tyre laws and the truth's parameter
columns."""

from __future__ import annotations

import numpy as np

from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.workbench import synth

TYRE_LAWS = [
    ((), [ford_escort().mu], {}),
    (("peak_tyre",), [0.45, 0.0], {"mf_peak": 0.45, "mf_exp": 0.0}),
    (("tire_saturation",), [1.0, 0.6], {"mu_peak": 0.6, "mu": 1.0}),
]
"""The tyre laws a tyre-hook effect is checked on: (base effects, their theta, the truth's
columns): the linear tyre, the magic formula and the brush tyre, each at a peak the states reach."""


def random_states(n: int = 9, seed: int = 0, pitch: bool = False):
    """``n`` random ST states with the steering-lag state (width 8) and, with ``pitch``, the
    pitch mode's two states (width 10; its acceleration away from a_x), and random inputs
    ``[steer_rate rad/s, accel m/s^2]``."""
    rng = np.random.default_rng(seed)
    s = np.zeros((n, 10 if pitch else 8))
    s[:, 3] = rng.uniform(8.0, 20.0, n)
    s[:, 5] = rng.normal(0.0, 0.3, n)
    s[:, 6] = rng.normal(0.0, 0.05, n)
    s[:, 2] = s[:, 7] = rng.normal(0.0, 0.05, n)
    if pitch:
        s[:, 8] = rng.normal(0.0, 2.0, n)
        s[:, 9] = rng.normal(0.0, 5.0, n)
    u = np.stack([rng.normal(0, 0.1, n), rng.uniform(-3.0, 2.0, n)], axis=1)
    return s, u


def truth_columns(n: int, **values: float) -> dict[str, np.ndarray]:
    """The Ford Escort's null truth (``synth.Truth()``) as ``n``-long columns, with ``values``
    (column names of :func:`synth.truth_columns`) set."""
    columns = synth.truth_columns(ford_escort(), [synth.Truth()] * n)
    unknown = set(values) - set(columns)
    if unknown:
        raise KeyError(f"not truth columns: {sorted(unknown)}")
    columns.update({k: np.full(n, float(v)) for k, v in values.items()})
    return columns
