"""Zero-shot terrain contexts: bounded HDBSCAN re-clustering, persistent ids, online assignment.

The paper (section IV-A, Algorithm 1) clusters every information vector z(t) seen so far with
HDBSCAN every 10 s and keeps cluster ids stable by matching centroids between runs. Clustering
everything stops being real time after ~15 minutes of driving, and the paper gives a frame no id
until the next re-clustering. :class:`ContextClusterer` keeps the paper's semantics with a bounded
cost:

* **Bounded store.** Frames are kept in strata: one uniform reservoir per context (Vitter's
  Algorithm R over all frames assigned to it, so the sample represents the whole history), plus a
  first-in-first-out window of the most recent unclustered (noise) frames, where a terrain never
  seen before accumulates at full density. Every stored frame carries a weight (how many frames it
  stands for), used for centroids and sizes. The store holds at most about ``max_stored`` vectors,
  whatever the length of the drive.
* **Re-clustering** (:meth:`ContextClusterer.recluster`) runs scikit-learn's HDBSCAN (no number of
  clusters) on the store, detaches small groups hanging off a cluster (they become noise), and
  re-forms the strata from the labels. At the start of a drive (one terrain only) HDBSCAN's
  densest core is grown into the whole terrain.
* **Persistence** (paper Algorithm 1): new centroids take the id of the closest previous centroid
  within epsilon; pairs are taken in order of increasing distance so one id goes to at most one
  cluster. Previous centroids include clusters that vanished earlier: they stay in the table and
  get their id back if they reappear. Unmatched clusters get fresh ids.
* **Online assignment** (:meth:`ContextClusterer.assign`): every frame gets an id at once, the id
  of its nearest stored member of a current cluster, if its k-th nearest member of that cluster
  passes the cluster's outlier gate (a high quantile of the members' own k-th-neighbour
  distances, times a margin); otherwise -1 (noise), so unseen terrain is not forced into a known
  context.

Parameters are given in physical terms where they have one (seconds of driving at the camera
rate); see ``docs/clustering.md``. Core module: numpy, scipy, scikit-learn (and its dependency
threadpoolctl), no pydrake.
"""

from __future__ import annotations

import copy
import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from sklearn.cluster import HDBSCAN
from threadpoolctl import threadpool_limits

NOISE = -1
"""Context id of frames that belong to no context (noise or unseen terrain)."""


@dataclass(frozen=True)
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
        if self.min_cluster_size < 2:
            raise ValueError(
                "ClusteringParams: min_cluster_duration_s * frame_rate_hz must give at least 2 "
                f"frames, got {self.min_cluster_duration_s!r} s * {self.frame_rate_hz!r} Hz"
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
    def min_reservoir(self) -> int:
        """Smallest per-context reservoir [frames]."""
        return max(2, round(self.min_reservoir_durations * self.min_cluster_size))


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


def hdbscan_labels(x: np.ndarray, min_cluster_size: int, min_samples: int) -> np.ndarray:
    """HDBSCAN labels of ``x`` (N, d) as the clusterer uses them (-1 = noise).

    scikit-learn's HDBSCAN with ``allow_single_cluster=False``. ``allow_single_cluster=True`` is
    not used: when terrains are joined by transition frames it returns the whole data as one
    cluster, and on one terrain alone it keeps only the densest ``min_cluster_size`` points.
    The one-terrain case (beginning of a drive: no cluster found although the data holds at least
    ``min_cluster_size`` frames) is handled by :meth:`ContextClusterer.recluster`.
    """
    x = np.asarray(x, dtype=float)
    if x.shape[0] < max(min_cluster_size, min_samples + 1, 2):
        return np.full(x.shape[0], NOISE, dtype=int)
    return _fit_hdbscan(x, min_cluster_size, min_samples, allow_single_cluster=False)


def _fit_hdbscan(
    x: np.ndarray, min_cluster_size: int, min_samples: int, *, allow_single_cluster: bool
) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        model = HDBSCAN(
            min_cluster_size=min_cluster_size,
            min_samples=min_samples,
            allow_single_cluster=allow_single_cluster,
            copy=True,
        )
        return model.fit_predict(x).astype(int)


def _kth_member_distances(members: np.ndarray, k: int) -> np.ndarray:
    """Leave-one-out distance of each row of ``members`` (M, d) to its k-th nearest other row."""
    m = members.shape[0]
    k = min(k, m - 1)
    if k < 1:
        return np.zeros(m)
    sq = (members * members).sum(1)
    out = np.empty(m)
    block = 1024
    for s in range(0, m, block):
        d2 = sq[s : s + block, None] - 2.0 * members[s : s + block] @ members.T + sq[None, :]
        d2[np.arange(d2.shape[0]), np.arange(s, s + d2.shape[0])] = np.inf
        out[s : s + block] = np.partition(d2, k - 1, axis=1)[:, k - 1]
    return np.sqrt(np.maximum(out, 0.0))


def _gate_radius(kth: np.ndarray, params: ClusteringParams, scale_sq: float) -> float:
    """Gate of a context from its members' k-th-neighbour distances (with a rounding floor)."""
    gate = params.gate_scale * float(np.quantile(kth, params.gate_quantile)) if kth.size else 0.0
    return max(gate, 1e-6 * (1.0 + math.sqrt(scale_sq)))


def detach_small_groups(
    x: np.ndarray, labels: np.ndarray, weights: np.ndarray, params: ClusteringParams
) -> np.ndarray:
    """Labels with the members of each cluster that are not connected to its body set to noise.

    HDBSCAN counts a group of fewer than ``min_cluster_size`` points that splits off a selected
    cluster as members of that cluster: the first frames of a new terrain next to a known one
    join the known context, and the outlier gate would then pass the new terrain's frames. Within
    each cluster, members are linked when closer than the cluster's gate; linked groups that
    stand for fewer than ``min_cluster_size`` frames (sum of weights) become noise.
    """
    out = labels.copy()
    for k in np.unique(labels[labels >= 0]):
        idx = np.flatnonzero(labels == k)
        members = x[idx]
        sq = (members * members).sum(1)
        d2 = np.maximum(sq[:, None] - 2.0 * members @ members.T + sq[None, :], 0.0)
        kk = min(params.gate_neighbours, idx.size - 1)
        if kk < 1:
            continue
        np.fill_diagonal(d2, np.inf)
        kth = np.sqrt(np.partition(d2, kk - 1, axis=1)[:, kk - 1])
        gate = _gate_radius(kth, params, float(sq.max()))
        n_comp, comp = connected_components(csr_matrix(d2 <= gate * gate), directed=False)
        if n_comp == 1:
            continue
        mass = np.bincount(comp, weights=weights[idx], minlength=n_comp)
        small = mass[comp] < params.min_cluster_size
        out[idx[small]] = NOISE
    return out


class _GateIndex:
    """Members of each context and their outlier gates; labels vectors by gated k-NN.

    A vector takes the context of its nearest member if its distance to the k-th nearest member
    of that context is at most the gate: ``gate_scale`` times the ``gate_quantile`` of the
    members' own leave-one-out k-th-neighbour distances. The k-th neighbour (not the first) makes
    the gate a density test, like HDBSCAN's core distance: a transition frame that happens to lie
    near one stray member is still noise.
    """

    def __init__(self, x: np.ndarray, ids: np.ndarray, params: ClusteringParams) -> None:
        order = np.argsort(ids, kind="stable")
        self.x = np.ascontiguousarray(x[order], dtype=float)
        self.ids = np.asarray(ids, dtype=int)[order]
        self.sq = (self.x * self.x).sum(1)
        self.k = params.gate_neighbours
        self.bounds: dict[int, tuple[int, int]] = {}
        self.gate_sq: dict[int, float] = {}
        for cid in np.unique(self.ids):
            s, e = np.searchsorted(self.ids, [cid, cid + 1])
            kth = _kth_member_distances(self.x[s:e], self.k)
            gate = _gate_radius(kth, params, float(self.sq[s:e].max()))
            self.bounds[int(cid)] = (int(s), int(e))
            self.gate_sq[int(cid)] = gate * gate

    @property
    def empty(self) -> bool:
        return self.ids.size == 0

    def labels(self, z: np.ndarray) -> np.ndarray:
        """Gated context ids of the rows of ``z`` (B, d); -1 where the gate rejects."""
        out = np.full(z.shape[0], NOISE, dtype=int)
        if self.empty or z.shape[0] == 0:
            return out
        d2 = self.sq[None, :] - 2.0 * (z @ self.x.T) + (z * z).sum(1)[:, None]
        cand = self.ids[d2.argmin(1)]
        for cid in np.unique(cand):
            rows = np.flatnonzero(cand == cid)
            s, e = self.bounds[int(cid)]
            kk = min(self.k, e - s)
            kth = np.partition(d2[rows, s:e], kk - 1, axis=1)[:, kk - 1]
            out[rows] = np.where(kth <= self.gate_sq[int(cid)], cid, NOISE)
        return out


class ContextClusterer:
    """Stores information vectors z, re-clusters on demand, assigns every frame an id at once.

    Usage::

        clusterer = ContextClusterer(ClusteringParams(frame_rate_hz=10.0))
        for t, z in frames:                 # every camera frame
            context_id = clusterer.assign(z, t)
            if t >= next_recluster_s:       # every 10 s
                clusterer.recluster(t)
        table = clusterer.table()

    All state (store, table, random generator) lives in the object; ``copy.deepcopy`` gives an
    independent clusterer (the LeafSystem keeps it in its abstract state).
    """

    def __init__(self, params: ClusteringParams | None = None) -> None:
        self.params = params if params is not None else ClusteringParams()
        self._rng = np.random.default_rng(self.params.seed)
        self._dim: int | None = None
        cap = self.params.max_stored
        self._x = np.zeros((0, 0))
        self._t = np.zeros(cap)
        self._w = np.zeros(cap)
        self._label = np.full(cap, NOISE, dtype=int)
        self._used = np.zeros(cap, dtype=bool)
        # Represented frame count and reservoir capacity of each context stratum.
        self._count: dict[int, float] = {}
        self._capacity = self.params.max_stored - self.params.noise_capacity
        self._records: dict[int, ClusterRecord] = {}
        self._next_id = 0
        self._recluster_time_s = math.nan
        self._n_reclusterings = 0
        self._last_recluster_duration_s = 0.0
        self._n_frames = 0
        # Assignment index: stored members of the active contexts and their gates.
        self._index = _GateIndex(np.zeros((0, 1)), np.zeros(0, dtype=int), self.params)

    # ----------------------------------------------------------------------------------------
    # Properties
    @property
    def dim(self) -> int | None:
        """Feature dimension (fixed by the first frame), None before it."""
        return self._dim

    @property
    def n_stored(self) -> int:
        """Vectors in the bounded store."""
        return int(self._used.sum())

    @property
    def n_frames(self) -> int:
        """Frames seen so far."""
        return self._n_frames

    @property
    def last_recluster_duration_s(self) -> float:
        """Wall-clock time of the latest re-clustering [s]."""
        return self._last_recluster_duration_s

    @property
    def stored_bytes(self) -> int:
        """Memory held by the store and the assignment index [bytes]."""
        arrays = (self._x, self._t, self._w, self._label, self._used, self._index.x)
        return int(sum(a.nbytes for a in arrays))

    def table(self) -> ClusterTable:
        """A copy of the cluster table."""
        records = [copy.deepcopy(self._records[k]) for k in sorted(self._records)]
        return ClusterTable(
            records=records,
            recluster_time_s=self._recluster_time_s,
            n_reclusterings=self._n_reclusterings,
            n_stored=self.n_stored,
        )

    # ----------------------------------------------------------------------------------------
    # Per-frame path
    def _check_vector(self, z: np.ndarray, name: str) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        if z.ndim != 1 or z.size == 0:
            raise ValueError(f"{name} must be a non-empty 1-D feature vector, got shape {z.shape}")
        if self._dim is not None and z.size != self._dim:
            raise ValueError(f"{name} has {z.size} numbers, but the clusterer holds {self._dim}")
        return z

    def predict(self, z: np.ndarray) -> np.ndarray:
        """Context ids of feature vectors without storing them.

        Args:
            z: (d,) or (N, d) feature vectors.

        Returns:
            (N,) int ids (-1 = noise / unseen / non-finite vector); a (d,) input gives a
            length-1 array.
        """
        z = np.atleast_2d(np.asarray(z, dtype=float))
        if self._dim is not None and z.shape[1] != self._dim:
            raise ValueError(f"z has {z.shape[1]} numbers per row, the clusterer holds {self._dim}")
        out = np.full(z.shape[0], NOISE, dtype=int)
        finite = np.flatnonzero(np.isfinite(z).all(1))
        block = 4096
        for s in range(0, finite.size, block):
            rows = finite[s : s + block]
            out[rows] = self._index.labels(z[rows])
        return out

    def assign(self, z: np.ndarray, t_s: float) -> int:
        """Give frame ``z`` (taken at time ``t_s`` [s]) a context id at once and store it.

        A non-finite vector (a corrupt frame) gets -1 and is not stored.
        """
        z = self._check_vector(z, "z")
        if not math.isfinite(t_s):
            raise ValueError(f"t_s must be finite, got {t_s!r}")
        if not np.isfinite(z).all():
            return NOISE
        if self._dim is None:
            self._dim = z.size
            self._x = np.zeros((self.params.max_stored, self._dim))
        self._n_frames += 1
        context_id = int(self._index.labels(z[None, :])[0])
        if context_id >= 0:
            rec = self._records[context_id]
            rec.size += 1.0
            rec.last_seen_s = max(rec.last_seen_s, t_s)
            self._store_in_context(z, t_s, context_id)
        else:
            self._store_noise(z, t_s)
        return context_id

    def _free_slot(self) -> int:
        free = np.flatnonzero(~self._used)
        if free.size:
            return int(free[0])
        grow = max(64, self._used.size // 4)
        self._x = np.vstack([self._x, np.zeros((grow, self._x.shape[1]))])
        self._t = np.concatenate([self._t, np.zeros(grow)])
        self._w = np.concatenate([self._w, np.zeros(grow)])
        self._label = np.concatenate([self._label, np.full(grow, NOISE, dtype=int)])
        self._used = np.concatenate([self._used, np.zeros(grow, dtype=bool)])
        return int(self._used.size - grow)

    def _put(self, slot: int, z: np.ndarray, t_s: float, label: int, weight: float) -> None:
        self._x[slot] = z
        self._t[slot] = t_s
        self._w[slot] = weight
        self._label[slot] = label
        self._used[slot] = True

    def _reservoir_capacity(self) -> int:
        n_active = sum(1 for r in self._records.values() if r.active)
        return max(self.params.min_reservoir, self._capacity // max(1, n_active))

    def _store_in_context(self, z: np.ndarray, t_s: float, context_id: int) -> None:
        """Algorithm R: a uniform sample of all frames ever assigned to the context."""
        self._count[context_id] = self._count.get(context_id, 0.0) + 1.0
        slots = np.flatnonzero(self._used & (self._label == context_id))
        if slots.size < self._reservoir_capacity():
            self._put(self._free_slot(), z, t_s, context_id, 1.0)
            return
        if self._rng.random() * self._count[context_id] < slots.size:
            self._put(int(slots[self._rng.integers(slots.size)]), z, t_s, context_id, 1.0)

    def _store_noise(self, z: np.ndarray, t_s: float) -> None:
        """First-in-first-out window of the newest unclustered frames."""
        slots = np.flatnonzero(self._used & (self._label == NOISE))
        if slots.size >= self.params.noise_capacity:
            slot = int(slots[self._t[slots].argmin()])
        else:
            slot = self._free_slot()
        self._put(slot, z, t_s, NOISE, 1.0)

    # ----------------------------------------------------------------------------------------
    # Re-clustering
    def recluster(self, t_s: float) -> ClusterTable:
        """Re-cluster the store with HDBSCAN, keep ids by Algorithm 1, rebuild strata and gates.

        Args:
            t_s: sim time of this re-clustering [s] (recorded in the table).

        Returns:
            The new cluster table.
        """
        start = time.perf_counter()
        # Small matrices: one BLAS thread is faster, and avoids contention with other processes.
        with threadpool_limits(limits=1, user_api="blas"):
            self._recluster()
        self._finish_recluster(t_s, start)
        return self.table()

    def _recluster(self) -> None:
        p = self.params
        slots = np.flatnonzero(self._used)
        if slots.size == 0:
            return
        x = self._x[slots]
        t = self._t[slots]
        w = self._w[slots].copy()
        old = self._label[slots]
        for cid, count in self._count.items():
            members = old == cid
            if members.any():
                w[members] = count / members.sum()

        raw = hdbscan_labels(x, p.min_cluster_size, p.min_samples)
        if raw.max(initial=NOISE) < 0 and slots.size >= p.min_cluster_size:
            raw = self._one_terrain_labels(x)
        raw = detach_small_groups(x, raw, w, p)

        ids = np.full(slots.size, NOISE, dtype=int)
        ks = [k for k in np.unique(raw) if k >= 0]
        if ks:
            cents = np.array([np.average(x[raw == k], axis=0, weights=w[raw == k]) for k in ks])
            known = sorted(self._records)
            prev = np.array([self._records[i].centroid for i in known]).reshape(
                len(known), x.shape[1]
            )
            eps = np.array([self._epsilon(self._records[i]) for i in known])
            match = match_centroids(prev, eps, cents)
            for r in self._records.values():
                r.active = False
            self._count = {}
            for k, cent, j in zip(ks, cents, match, strict=True):
                members = raw == k
                cid = known[j] if j >= 0 else self._new_id()
                ids[members] = cid
                size = float(w[members].sum())
                radius = float(
                    np.sqrt(np.average(((x[members] - cent) ** 2).sum(1), weights=w[members]))
                )
                if cid in self._records:
                    rec = self._records[cid]
                    rec.centroid = cent
                    rec.size = size
                    rec.radius = radius
                    rec.active = True
                    rec.first_seen_s = min(rec.first_seen_s, float(t[members].min()))
                    rec.last_seen_s = max(rec.last_seen_s, float(t[members].max()))
                else:
                    self._records[cid] = ClusterRecord(
                        context_id=cid,
                        centroid=cent,
                        size=size,
                        first_seen_s=float(t[members].min()),
                        last_seen_s=float(t[members].max()),
                        active=True,
                        radius=radius,
                    )
                self._count[cid] = size
        else:
            for r in self._records.values():
                r.active = False
            self._count = {}

        self._restratify(slots, ids, w)
        self._rebuild_index()

    def _one_terrain_labels(self, x: np.ndarray) -> np.ndarray:
        """One cluster (one terrain so far): HDBSCAN's densest core, grown by the outlier gate.

        With ``allow_single_cluster=True`` HDBSCAN keeps only the densest ``min_cluster_size``
        points of a lone cluster. The core is grown like a flood fill: every point that passes
        the gate of the current members joins, the gate is recomputed from the members, until
        nothing changes (at most 10 rounds). Points of lower density (outliers, the first frames
        of a next terrain) stay noise.
        """
        p = self.params
        labels = _fit_hdbscan(x, p.min_cluster_size, p.min_samples, allow_single_cluster=True)
        if labels.max(initial=NOISE) != 0:
            return labels
        for _ in range(10):
            members = labels == 0
            grown = _GateIndex(x[members], labels[members], p).labels(x)
            grown[members] = 0
            if np.array_equal(grown, labels):
                break
            labels = grown
        return labels

    def _epsilon(self, rec: ClusterRecord) -> float:
        if self.params.persistence_epsilon is not None:
            return self.params.persistence_epsilon
        return self.params.persistence_scale * max(rec.radius, 1e-12)

    def _new_id(self) -> int:
        cid = self._next_id
        self._next_id += 1
        return cid

    def _restratify(self, slots: np.ndarray, ids: np.ndarray, w: np.ndarray) -> None:
        """Move stored frames to their new strata and trim every stratum to its capacity."""
        keep = np.ones(slots.size, dtype=bool)
        cap = self._reservoir_capacity()
        for cid in np.unique(ids):
            members = np.flatnonzero(ids == cid)
            if cid == NOISE:
                if members.size > self.params.noise_capacity:
                    newest = np.argsort(self._t[slots[members]], kind="stable")[::-1]
                    keep[members[newest[self.params.noise_capacity :]]] = False
                continue
            if members.size > cap:
                prob = w[members] / w[members].sum()
                chosen = self._rng.choice(members.size, size=cap, replace=False, p=prob)
                drop = np.ones(members.size, dtype=bool)
                drop[chosen] = False
                keep[members[drop]] = False
        self._label[slots] = ids
        self._w[slots] = w
        self._used[slots[~keep]] = False
        self._label[slots[~keep]] = NOISE
        for cid in self._count:
            kept = self._used & (self._label == cid)
            self._w[kept] = self._count[cid] / max(1, kept.sum())

    def _rebuild_index(self) -> None:
        """Exemplars (stored members of active contexts) and per-context gates."""
        members = self._used & (self._label >= 0)
        self._index = _GateIndex(self._x[members], self._label[members], self.params)

    def _finish_recluster(self, t_s: float, start: float) -> None:
        self._recluster_time_s = float(t_s)
        self._n_reclusterings += 1
        self._last_recluster_duration_s = time.perf_counter() - start


def full_hdbscan_labels(x: np.ndarray, params: ClusteringParams | None = None) -> np.ndarray:
    """Reference labels: HDBSCAN over all of ``x`` with the clusterer's parameters.

    What the paper does every 10 s (cost grows like N^2); used to measure how faithful the bounded
    scheme is. Ids are HDBSCAN's own labels (not persistent).
    """
    p = params if params is not None else ClusteringParams()
    return hdbscan_labels(np.asarray(x, dtype=float), p.min_cluster_size, p.min_samples)
