"""Settings of the context clustering (:class:`ClusteringParams`) and the noise id."""

from __future__ import annotations

import math
from dataclasses import dataclass

NOISE = -1
"""Context id of frames that belong to no context (noise or unseen terrain)."""
MAX_ABS_FEATURE = 1e100
"""Largest |component| of a usable feature vector. CLIP features are unit vectors and the
descriptor's are O(1); far beyond, squared distances overflow to inf (from ~1e154) and HDBSCAN
exhausts memory. Larger vectors are treated like non-finite ones: a corrupt frame."""


MAX_STORED = 10_000
"""Most stored feature vectors: each re-clustering runs HDBSCAN over every stored one (time and
memory grow with their count squared: 10 000 frames, ~0.8 GB of pairwise distances)."""


@dataclass
class ClusteringParams:
    """Settings of :class:`ContextClusterer`.

    Attributes:
        frame_rate_hz: camera (feature) rate [Hz]; converts the durations below to frame counts.
        min_cluster_duration_s: seconds of driving on one terrain before it can form a context
            (HDBSCAN ``min_cluster_size`` = this times the rate). Default 5 s = 50 frames at 10 Hz:
            a terrain crossed for 20 s per lap becomes a context at the first re-clustering after
            5 s on it, while a transition strip (a few metres at ~8 m/s, < 1 s) never does.
        min_samples_duration_s: seconds of frames in a frame's neighbourhood for it to count as
            dense (HDBSCAN ``min_samples``); default 1 s = 10 frames.
        noise_memory_s: seconds of unclustered frames kept (newest first) so that a new terrain
            accumulates until it forms a context; default 60 s (capped at a third of
            ``max_stored``).
        max_stored: budget of stored vectors (all contexts' reservoirs plus the noise window);
            bounds memory and the re-clustering time (HDBSCAN cost grows like its square).
        min_reservoir_durations: each context keeps at least this many times
            ``min_cluster_size`` frames, even when many contexts share ``max_stored``.
        gate_neighbours: k of the outlier gate: a frame joins the context of its nearest stored
            member only if its k-th nearest member of that context is within the gate.
        gate_quantile: quantile of the members' own (leave-one-out) k-th-neighbour distances
            that sets the gate of a context.
        gate_scale: margin on that quantile (gate = gate_scale * quantile).
        persistence_epsilon: Algorithm 1 threshold in feature units; None (default) means
            ``persistence_scale`` times the previous cluster's RMS radius, which adapts to the
            feature backend (CLIP or descriptor vectors have different scales).
        persistence_scale: see ``persistence_epsilon``.
        seed: seed of the reservoir sampling.
        novelty_window_s: novelty-triggered re-clustering (None, the default: off, the paper's
            periodic re-clustering only). When the frames of the last ``novelty_window_s``
            seconds were mostly noise (at least ``novelty_fraction`` of the frames the camera
            rate gives in that time), a terrain not seen before has gathered enough frames to
            form a context: :meth:`ContextClusterer.novelty_due` says so, and the system
            re-clusters at once instead of waiting for the period. At least
            ``min_cluster_duration_s`` (a shorter window could not hold a cluster).
        novelty_fraction: share of noise frames in the window that triggers, in (0, 1].
        novelty_min_interval_s: at most one triggered re-clustering per this many seconds after
            any re-clustering (bounds the cost while a terrain stays noise).
        continuation_gate_scale: None (default, the paper's design: off) or a factor >= 1. A
            frame the outlier gate rejects is still reported as the context of the frame before
            it (the visit continues) when its k-th nearest member of that context is within this
            many times that context's gate; it is stored as noise (re-clustering decides as
            always). The frame must also be nearest to a member of that context. A terrain not
            seen before, far from every context, stays noise; only a frame near the context the
            car was just on continues the visit (docs/clustering.md, "Continuing a visit").
        continuation_hold_s: None (default: a frame beyond the widened gate ends the visit) or
            seconds >= 0 (needs ``continuation_gate_scale``): such a frame is noise but leaves
            the visit open while its nearest member is of the visit's context and that context
            was reported within this many seconds; a later frame within the widened gate then
            continues the visit (one blurred frame just beyond it would end a visit for good).
            With the car's speed given (``ContextClusterer.assign``), the hold, and after it every
            frame that would continue the visit until one passes the context's own gate, needs
            the camera's blur to explain it: the car faster than every member of the context
            was taken at; else the frame is noise and ends the visit (a strip, then other ground
            within the widened gate, must not be handed the context's friction).
    """

    frame_rate_hz: float = 10.0
    min_cluster_duration_s: float = 5.0
    min_samples_duration_s: float = 5.0
    noise_memory_s: float = 60.0
    max_stored: int = 2000
    min_reservoir_durations: float = 2.0
    gate_neighbours: int = 3
    gate_quantile: float = 0.99
    gate_scale: float = 1.25
    persistence_epsilon: float | None = None
    persistence_scale: float = 1.5
    seed: int = 0
    novelty_window_s: float | None = None
    novelty_fraction: float = 0.8
    novelty_min_interval_s: float = 1.0
    continuation_gate_scale: float | None = None
    continuation_hold_s: float | None = None

    def __post_init__(self) -> None:
        positive = (
            "frame_rate_hz",
            "min_cluster_duration_s",
            "min_samples_duration_s",
            "noise_memory_s",
            "min_reservoir_durations",
            "gate_scale",
            "persistence_scale",
        )
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(
                    f"ClusteringParams.{name} must be a positive number, got {value!r}"
                )
        if not (isinstance(self.gate_neighbours, int) and self.gate_neighbours >= 1):
            raise ValueError(
                "ClusteringParams.gate_neighbours must be an int >= 1, got "
                f"{self.gate_neighbours!r}"
            )
        if not 0.0 < self.gate_quantile <= 1.0:
            raise ValueError(
                f"ClusteringParams.gate_quantile must be in (0, 1], got {self.gate_quantile!r}"
            )
        if self.persistence_epsilon is not None and not (
            math.isfinite(self.persistence_epsilon) and self.persistence_epsilon > 0
        ):
            raise ValueError(
                "ClusteringParams.persistence_epsilon must be None or a positive number, got "
                f"{self.persistence_epsilon!r}"
            )
        if self.novelty_window_s is not None and not (
            isinstance(self.novelty_window_s, int | float)
            and math.isfinite(self.novelty_window_s)
            and self.novelty_window_s >= self.min_cluster_duration_s
        ):
            raise ValueError(
                "ClusteringParams.novelty_window_s must be None (off) or a number of seconds >= "
                f"min_cluster_duration_s ({self.min_cluster_duration_s!r}), got "
                f"{self.novelty_window_s!r}"
            )
        if not (
            isinstance(self.novelty_fraction, int | float) and 0.0 < self.novelty_fraction <= 1.0
        ):
            raise ValueError(
                "ClusteringParams.novelty_fraction must be in (0, 1], got "
                f"{self.novelty_fraction!r}"
            )
        if not (
            isinstance(self.novelty_min_interval_s, int | float)
            and math.isfinite(self.novelty_min_interval_s)
            and self.novelty_min_interval_s > 0
        ):
            raise ValueError(
                "ClusteringParams.novelty_min_interval_s must be a positive number of seconds, "
                f"got {self.novelty_min_interval_s!r}"
            )
        scale = self.continuation_gate_scale
        if scale is not None and not (
            isinstance(scale, int | float) and math.isfinite(scale) and scale >= 1.0
        ):
            raise ValueError(
                "ClusteringParams.continuation_gate_scale must be None (off) or a number >= 1 "
                f"(a multiple of the outlier gate), got {scale!r}"
            )
        hold = self.continuation_hold_s
        if hold is not None and not (
            isinstance(hold, int | float) and math.isfinite(hold) and hold >= 0 and scale
        ):
            raise ValueError(
                "ClusteringParams.continuation_hold_s must be None (off) or seconds >= 0, and "
                f"needs continuation_gate_scale (got {hold!r}, scale {scale!r})"
            )
        if self.min_cluster_size < 2:
            raise ValueError(
                "ClusteringParams: min_cluster_duration_s * frame_rate_hz must give at least 2 "
                f"frames, got {self.min_cluster_duration_s!r} s * {self.frame_rate_hz!r} Hz"
            )
        if self.max_stored > MAX_STORED:
            n = self.max_stored
            raise ValueError(
                f"ClusteringParams.max_stored={n!r} must be <= {MAX_STORED} frames (every "
                f"re-clustering runs HDBSCAN over all of them: its pairwise distances alone would "
                f"take ~{n * n * 8 / 1e9:.3g} GB)"
            )
        if self.max_stored < self.noise_capacity + self.min_reservoir:
            raise ValueError(
                f"ClusteringParams.max_stored={self.max_stored!r} is smaller than the noise window "
                f"({self.noise_capacity} frames) plus one context reservoir ({self.min_reservoir})"
            )

    @property
    def min_cluster_size(self) -> int:
        """HDBSCAN ``min_cluster_size`` [frames]."""
        return max(2, round(self.min_cluster_duration_s * self.frame_rate_hz))

    @property
    def min_samples(self) -> int:
        """HDBSCAN ``min_samples`` [frames]."""
        return max(1, round(self.min_samples_duration_s * self.frame_rate_hz))

    @property
    def noise_capacity(self) -> int:
        """Frames of the noise window (``noise_memory_s``, at most a third of ``max_stored``)."""
        window = min(round(self.noise_memory_s * self.frame_rate_hz), self.max_stored // 3)
        return max(self.min_cluster_size, window)

    @property
    def novelty_frames(self) -> int | None:
        """Noise frames within ``novelty_window_s`` that trigger a re-clustering (None: off)."""
        if self.novelty_window_s is None:
            return None
        frames = self.novelty_fraction * self.novelty_window_s * self.frame_rate_hz
        return max(1, math.ceil(frames - 1e-9))  # 0.8 * 6 s * 10 Hz is 48, not 48.000...1

    @property
    def min_reservoir(self) -> int:
        """Smallest per-context reservoir [frames]."""
        return max(2, round(self.min_reservoir_durations * self.min_cluster_size))
