"""The table of contexts and their persistence between re-clusterings (paper Algorithm 1).

:class:`ClusterRecord` / :class:`ClusterTable`: every context discovered so far, active or
vanished; :func:`match_centroids`: which previous context each new cluster inherits its id from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class ClusterRecord:
    """One context in the table.

    Attributes:
        context_id: persistent id (>= 0).
        centroid: weighted mean of its frames' feature vectors (same units as z).
        size: number of frames it stands for (assigned online or at re-clustering).
        first_seen_s: time of its earliest frame [s].
        last_seen_s: time of its latest frame [s].
        active: found by the latest re-clustering (vanished contexts stay with active=False).
        radius: RMS distance of its frames to the centroid (feature units).
    """

    context_id: int
    centroid: np.ndarray
    size: float
    first_seen_s: float
    last_seen_s: float
    active: bool = True
    radius: float = 0.0


@dataclass
class ClusterTable:
    """All contexts discovered so far (active and vanished), ordered by id.

    Attributes:
        records: one :class:`ClusterRecord` per id.
        recluster_time_s: sim time of the latest re-clustering [s] (nan before the first).
        n_reclusterings: number of re-clusterings so far.
        n_stored: vectors in the bounded store.
    """

    records: list[ClusterRecord] = field(default_factory=list)
    recluster_time_s: float = math.nan
    n_reclusterings: int = 0
    n_stored: int = 0

    @property
    def ids(self) -> list[int]:
        """Ids of all contexts, active or not."""
        return [r.context_id for r in self.records]

    @property
    def active_ids(self) -> list[int]:
        """Ids found by the latest re-clustering."""
        return [r.context_id for r in self.records if r.active]

    def record(self, context_id: int) -> ClusterRecord:
        """The record of ``context_id``; KeyError naming the id if unknown."""
        for r in self.records:
            if r.context_id == context_id:
                return r
        raise KeyError(f"context_id {context_id!r} is not in the cluster table (ids {self.ids})")


@dataclass
class StoredFeatures:
    """A copy of the clusterer's bounded store (for views and tools; never fed back).

    Attributes:
        z: (N, D) stored information vectors.
        labels: (N,) their context ids as of the latest re-clustering or assignment (-1 noise).
        t_s: (N,) times the frames were taken [s].
        n_reclusterings: re-clusterings so far when the copy was taken.
    """

    z: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    labels: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_reclusterings: int = 0


@dataclass(frozen=True)
class FrameLabels:
    """The stored frames' times and labels as the clustering now stands (paper eq. 5d).

    What a consumer needs to relabel its own time-stamped data after a re-clustering, without
    the feature vectors: every frame in the clusterer's bounded store, its time and its current
    label (the latest re-clustering's, with persistent ids; frames taken since then carry their
    online label).

    Attributes:
        t_s: (N,) times the frames were taken [s], increasing.
        labels: (N,) their context ids (-1 noise).
        version: re-clusterings so far (the labels change at a re-clustering; between two, frames
            are only added or dropped).
        frame_period_s: the camera period [s]: a frame taken at ``t_f`` is the context id from
            ``t_f`` until the next frame (the clustering's output is a zero-order hold), so it
            covers the data sampled in ``(t_f, t_f + frame_period_s]``.
    """

    t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    labels: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    version: int = 0
    frame_period_s: float = math.nan


def match_centroids(
    previous: np.ndarray,
    epsilons: np.ndarray,
    current: np.ndarray,
) -> np.ndarray:
    """Paper Algorithm 1 (centroid-based context persistence) with a one-to-one rule.

    Args:
        previous: (J, d) previous centroids.
        epsilons: (J,) match threshold of each previous centroid (feature units).
        current: (K, d) new centroids.

    Returns:
        (K,) int: index j of the previous centroid each new centroid inherits its id from, or -1
        for a new centroid that gets a fresh id. Each previous centroid is matched to its nearest
        new centroid if closer than its epsilon (as in Algorithm 1); when two previous centroids
        claim the same new one, the closer pair wins (pairs are taken by increasing distance).
    """
    previous = np.atleast_2d(np.asarray(previous, dtype=float))
    current = np.atleast_2d(np.asarray(current, dtype=float))
    result = np.full(current.shape[0], -1, dtype=int)
    if previous.shape[0] == 0 or current.shape[0] == 0:
        return result
    dist = np.sqrt(((previous[:, None, :] - current[None, :, :]) ** 2).sum(-1))
    nearest = dist.argmin(axis=1)
    nearest_d = dist[np.arange(previous.shape[0]), nearest]
    for j in np.argsort(nearest_d, kind="stable"):
        k = nearest[j]
        if nearest_d[j] < epsilons[j] and result[k] < 0:
            result[k] = j
    return result
