"""Synthetic information-vector streams with a planted truth, for clustering tests and benchmarks.

A stream imitates what ClipFeatures emits while the car laps a course: each terrain has its own
caption-similarity profile (a softmax over ``n_captions`` logits) and mean colour (weighted by
``lambda_c`` = 0.25, as in the paper's eq. 4); frames of one terrain scatter around it, transition
strips blend the two neighbouring terrains, a small fraction of frames are outliers (glare, motion
blur), and a slow drift imitates changing light. Labels: terrain index >= 0, :data:`TRANSITION`,
:data:`OUTLIER`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

TRANSITION = -1
"""Label of frames taken on a transition strip between two terrains."""
OUTLIER = -2
"""Label of outlier frames (no terrain)."""


@dataclass(frozen=True)
class FeatureStream:
    """A synthetic stream: ``t_s`` (N,) [s], ``z`` (N, d) feature vectors, ``label`` (N,) int."""

    t_s: np.ndarray
    z: np.ndarray
    label: np.ndarray

    def head(self, n: int) -> FeatureStream:
        """The first ``n`` frames."""
        return FeatureStream(self.t_s[:n], self.z[:n], self.label[:n])


def _softmax(a: np.ndarray) -> np.ndarray:
    a = a - a.max(-1, keepdims=True)
    e = np.exp(a)
    return e / e.sum(-1, keepdims=True)


def synthetic_feature_stream(
    *,
    n_laps: int = 4,
    terrain_durations_s: Sequence[float] = (25.0, 22.0, 30.0, 24.0),
    transition_s: float = 0.6,
    rate_hz: float = 10.0,
    n_captions: int = 33,
    late_terrain_from_lap: int | None = None,
    late_terrain_duration_s: float = 25.0,
    outlier_fraction: float = 0.01,
    within_spread: float = 0.35,
    drift: float = 0.0,
    drift_period_s: float = 600.0,
    lambda_c: float = 0.25,
    seed: int = 0,
) -> FeatureStream:
    """Frames of ``n_laps`` laps over terrains 0..K-1 in order, each lap ``terrain_durations_s``.

    Args:
        n_laps: laps driven.
        terrain_durations_s: seconds spent on each terrain per lap.
        transition_s: seconds on each transition strip (frames blend the two terrains).
        rate_hz: camera rate [Hz].
        n_captions: caption similarities per frame (the vector has n_captions + 3 numbers).
        late_terrain_from_lap: if set, an extra terrain (label K) is appended to every lap from this
            lap (0-based) on: a terrain never seen before appearing late.
        late_terrain_duration_s: seconds on the extra terrain per lap.
        outlier_fraction: fraction of frames replaced by outliers.
        within_spread: standard deviation of the per-frame logit noise (terrain texture variety).
        drift: amplitude of a slow logit and colour drift (light), 0 = none.
        drift_period_s: period of that drift [s].
        lambda_c: weight of the mean colour in the vector.
        seed: random seed.
    """
    if n_laps < 1 or rate_hz <= 0 or len(terrain_durations_s) < 1:
        raise ValueError(
            f"need n_laps >= 1, rate_hz > 0 and at least one terrain, got n_laps={n_laps!r}, "
            f"rate_hz={rate_hz!r}, terrain_durations_s={terrain_durations_s!r}"
        )
    rng = np.random.default_rng(seed)
    n_base = len(terrain_durations_s)
    n_terrains = n_base + (1 if late_terrain_from_lap is not None else 0)
    logits = rng.normal(0.0, 1.5, (n_terrains, n_captions))
    rgb = rng.uniform(0.2, 0.8, (n_terrains, 3))
    drift_dir = rng.normal(0.0, 1.0, n_captions)
    dt = 1.0 / rate_hz

    def frames(k: int, t0: float, n: int) -> np.ndarray:
        tt = t0 + dt * np.arange(n)
        light = drift * np.sin(2.0 * np.pi * tt / drift_period_s)[:, None]
        lg = logits[k] + rng.normal(0.0, within_spread, (n, n_captions)) + light * drift_dir
        col = rgb[k] * (1.0 + 0.3 * light) + rng.normal(0.0, 0.03, (n, 3))
        return np.concatenate([_softmax(lg), lambda_c * col], axis=1)

    segments: list[int] = []
    for lap in range(n_laps):
        segments += list(range(n_base))
        if late_terrain_from_lap is not None and lap >= late_terrain_from_lap:
            segments.append(n_base)
    z_parts: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    t0 = 0.0
    prev: int | None = None
    n_trans = max(1, round(transition_s * rate_hz))
    for k in segments:
        if prev is not None:
            a = np.linspace(0.0, 1.0, n_trans + 2)[1:-1, None]
            z_parts.append((1.0 - a) * frames(prev, t0, n_trans) + a * frames(k, t0, n_trans))
            labels.append(np.full(n_trans, TRANSITION))
            t0 += n_trans * dt
        dur = terrain_durations_s[k] if k < n_base else late_terrain_duration_s
        n = max(1, round(dur * rate_hz))
        z_parts.append(frames(k, t0, n))
        labels.append(np.full(n, k))
        t0 += n * dt
        prev = k
    z = np.concatenate(z_parts)
    label = np.concatenate(labels).astype(int)
    out = rng.random(z.shape[0]) < outlier_fraction
    n_out = int(out.sum())
    z[out] = np.concatenate(
        [_softmax(rng.normal(0.0, 2.0, (n_out, n_captions))), lambda_c * rng.random((n_out, 3))],
        axis=1,
    )
    label[out] = OUTLIER
    return FeatureStream(t_s=dt * np.arange(z.shape[0]), z=z, label=label)
