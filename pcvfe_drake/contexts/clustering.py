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
rate); see ``docs/clustering.md``. Modules: this one (the clusterer: store, re-clustering,
assignment), ``clustering_params`` (settings), ``cluster_table`` (the table and Algorithm 1),
``density_gate`` (HDBSCAN, neighbour distances, outlier gates); the public names of all four are
importable from here. Core: numpy, scipy, scikit-learn (and its dependency threadpoolctl), no
pydrake.
"""

from __future__ import annotations

import copy
import math
import time
import warnings

import numpy as np

from pcvfe_drake.blas_threads import one_blas_thread
from pcvfe_drake.contexts.cluster_table import (
    ClusterRecord,
    ClusterTable,
    FrameLabels,
    StoredFeatures,
    match_centroids,
)
from pcvfe_drake.contexts.clustering_params import MAX_ABS_FEATURE, NOISE, ClusteringParams
from pcvfe_drake.contexts.density_gate import (
    GateIndex,
    detach_small_groups,
    fit_hdbscan,
    full_hdbscan_labels,
    hdbscan_labels,
)
from pcvfe_drake.shallow_copy import CopiedOnDraw, shallow_copy

__all__ = [
    "MAX_ABS_FEATURE",
    "NOISE",
    "ClusterRecord",
    "ClusterTable",
    "ClusteringParams",
    "ContextClusterer",
    "FrameLabels",
    "StoredFeatures",
    "detach_small_groups",
    "full_hdbscan_labels",
    "hdbscan_labels",
    "match_centroids",
]


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
        self._rng = CopiedOnDraw(np.random.default_rng(self.params.seed))
        self._dim: int | None = None
        cap = self.params.max_stored
        self._x = np.zeros((0, 0))
        self._t = np.zeros(cap)
        self._v = np.full(cap, math.nan)  # the car's speed when each frame was taken [m/s]
        self._w = np.zeros(cap)
        self._label = np.full(cap, NOISE, dtype=int)
        self._used = np.zeros(cap, dtype=bool)
        # Represented frame count and reservoir capacity of each context stratum.
        self._count: dict[int, float] = {}
        self._capacity = self.params.max_stored - self.params.noise_capacity
        self._records: dict[int, ClusterRecord] = {}
        self._next_id = 0
        self._recluster_time_s = math.nan
        self._novelty_try_s = math.nan
        self._n_novelty_tries = 0
        self._n_novelty_kept = 0
        self._n_reclusterings = 0
        self._last_recluster_duration_s = 0.0
        self._n_frames = 0
        self._n_rejected = 0
        self._warned_scale = False
        # Context reported for the latest frame (the visit a rejected frame may continue).
        self._visit = NOISE
        self._continued_frames = 0
        self._visit_seen_s = -math.inf  # when the visit's context was last reported
        self._evidence = "noise"
        self._left = False  # a frame of the visit was beyond even the widened gate (held)
        # Fastest speed [m/s] at which a member of each context the gate measures against was
        # taken (NaN: some member's speed unknown); set with the index.
        self._member_speed: dict[int, float] = {}
        # Assignment index: stored members of the active contexts and their gates.
        self._index = GateIndex(np.zeros((0, 1)), np.zeros(0, dtype=int), self.params)

    def __deepcopy__(self, memo) -> ContextClusterer:
        # An independent clusterer, copying only what its methods write into: the store's
        # arrays (written row by row), the records (their fields are updated), the counts and
        # the random generator. The parameters, the gate index and the members' speeds are never
        # written (they are rebuilt whole), so the copies share them. The feature store (2000
        # rows of a frame's features) is shared read-only and copied by the first write
        # (``_put``): most frames write none of it (a full reservoir keeps a frame with the
        # probability of its share), and Drake copies the state at every frame.
        other = shallow_copy(self)
        for name in ("_t", "_v", "_w", "_label", "_used"):
            setattr(other, name, getattr(self, name).copy())
        self._x.flags.writeable = False
        other._count = dict(self._count)
        other._records = {k: shallow_copy(r) for k, r in self._records.items()}
        other._rng = copy.deepcopy(self._rng)
        return other

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
    def n_rejected(self) -> int:
        """Frames refused as corrupt: non-finite or beyond ``MAX_ABS_FEATURE``."""
        return self._n_rejected

    @property
    def last_recluster_duration_s(self) -> float:
        """Wall-clock time of the latest re-clustering [s]."""
        return self._last_recluster_duration_s

    @property
    def stored_bytes(self) -> int:
        """Memory held by the store and the assignment index [bytes]."""
        arrays = (self._x, self._t, self._v, self._w, self._label, self._used, self._index.x)
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

    def stored(self) -> StoredFeatures:
        """A copy of the stored vectors with their labels and times."""
        if self._dim is None:
            return StoredFeatures(n_reclusterings=self._n_reclusterings)
        used = self._used
        return StoredFeatures(
            z=self._x[used], labels=self._label[used], t_s=self._t[used],
            n_reclusterings=self._n_reclusterings,
        )  # fmt: skip

    def frame_labels(self, frame_period_s: float | None = None) -> FrameLabels:
        """The stored frames' times and current labels, time-ordered (no feature vectors).

        Args:
            frame_period_s: the camera period [s] (default ``1 / params.frame_rate_hz``).
        """
        period = 1.0 / self.params.frame_rate_hz if frame_period_s is None else frame_period_s
        used = np.flatnonzero(self._used)
        order = used[np.argsort(self._t[used], kind="stable")]
        return FrameLabels(
            t_s=self._t[order].copy(),
            labels=self._label[order].copy(),
            version=self._n_reclusterings,
            frame_period_s=float(period),
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
        with np.errstate(invalid="ignore"):
            finite = np.flatnonzero((np.abs(z) <= MAX_ABS_FEATURE).all(1))
        block = 4096
        for s in range(0, finite.size, block):
            rows = finite[s : s + block]
            out[rows] = self._index.labels(z[rows])
        return out

    def assign(self, z: np.ndarray, t_s: float, speed_mps: float | None = None) -> int:
        """Give frame ``z`` (taken at time ``t_s`` [s], the car at ``speed_mps`` [m/s]) a
        context id at once and store it.

        A corrupt frame (a non-finite vector, or a component beyond ``MAX_ABS_FEATURE``) gets -1
        and is not stored; the first one beyond the bound warns. The speed decides whether a
        frame the gate rejects may continue the visit (:meth:`_blur_explains`); None: unknown.
        """
        z = self._check_vector(z, "z")
        if not math.isfinite(t_s):
            raise ValueError(f"t_s must be finite, got {t_s!r}")
        v = math.nan if speed_mps is None else float(speed_mps)
        self._evidence = "corrupt"
        if not np.isfinite(z).all():
            self._n_rejected += 1
            return NOISE
        if np.abs(z).max() > MAX_ABS_FEATURE:
            if not self._warned_scale:
                self._warned_scale = True
                warnings.warn(
                    f"ContextClusterer: feature vector at t = {t_s:g} s has |z| up to "
                    f"{np.abs(z).max():.3g} (> {MAX_ABS_FEATURE:g}); such frames are treated as "
                    "corrupt (context -1, not stored). Check the feature extractor's scaling.",
                    RuntimeWarning,
                    stacklevel=2,
                )
            self._n_rejected += 1
            return NOISE
        if self._dim is None:
            self._dim = z.size
            self._x = np.zeros((self.params.max_stored, self._dim))
        self._n_frames += 1
        context_id = int(self._index.labels(z[None, :])[0])
        self._evidence = "gate" if context_id >= 0 else "noise"
        if context_id == NOISE and self._visit >= 0:
            continues = self._continues_visit(z)
            held = not continues and self._visit_held(z, t_s)
            if (held or (continues and self._left)) and not self._blur_explains(v):
                self._evidence = "unexplained"  # noise, and the visit ends
            elif continues:
                self._continued_frames += 1
                self._visit_seen_s = t_s
                self._store_noise(z, t_s, v)
                self._evidence = "continued"
                return self._visit
            elif held:
                self._left = True
                self._store_noise(z, t_s, v)  # noise, but the visit stays open
                self._evidence = "held"
                return NOISE
        self._visit = context_id
        self._left = False
        self._visit_seen_s = t_s
        if context_id >= 0:
            rec = self._records[context_id]
            rec.size += 1.0
            rec.last_seen_s = max(rec.last_seen_s, t_s)
            self._store_in_context(z, t_s, v, context_id)
        else:
            self._store_noise(z, t_s, v)
        return context_id

    def _blur_explains(self, v: float) -> bool:
        """Whether the camera's motion blur can explain a frame of the visit's context that
        its gate rejects: the car (at ``v`` [m/s]) is faster than every member the gate
        measures against was taken at. Blur grows with speed; at a speed the members cover,
        the gate already holds frames as blurred, so a frame beyond it may be other ground,
        and its friction must not be handed as the context's (less friction at once). True
        where a speed is unknown (the frame's or a member's): no evidence either way."""
        bound = self._member_speed.get(self._visit, math.nan)
        return not (math.isfinite(v) and math.isfinite(bound)) or v > bound

    @property
    def last_evidence(self) -> str:
        """How the latest frame got its id: ``gate`` (its context's gate), ``continued``
        (the widened gate, :meth:`_continues_visit`), ``held`` (noise, the visit held open),
        ``unexplained`` (it would have continued or held the visit, but blur cannot explain
        it at the car's speed: noise, the visit ends), ``noise`` or ``corrupt``."""
        return self._evidence

    def _continues_visit(self, z: np.ndarray) -> bool:
        """A frame the gate rejects continues the visit of the previous frame's context when it
        passes that context's gate widened ``params.continuation_gate_scale`` times (None:
        never)."""
        scale = self.params.continuation_gate_scale
        if scale is None or self._visit < 0:
            return False
        return self._index.within(z, self._visit, scale)

    def _visit_held(self, z: np.ndarray, t_s: float) -> bool:
        """A frame beyond the widened gate leaves the visit open when its nearest stored member
        still belongs to the visit's context and that context was reported within the last
        ``params.continuation_hold_s`` (None: the frame ends the visit)."""
        hold = self.params.continuation_hold_s
        if hold is None or self._visit < 0 or t_s - self._visit_seen_s > hold + 1e-9:
            return False
        return self._index.within(z, self._visit, math.inf)

    @property
    def continued_frames(self) -> int:
        """Frames reported as the previous frame's context by the widened gate
        (``continuation_gate_scale``) so far."""
        return self._continued_frames

    def _free_slot(self) -> int:
        free = np.flatnonzero(~self._used)
        if free.size:
            return int(free[0])
        grow = max(64, self._used.size // 4)
        self._x = np.vstack([self._x, np.zeros((grow, self._x.shape[1]))])
        self._t = np.concatenate([self._t, np.zeros(grow)])
        self._v = np.concatenate([self._v, np.full(grow, math.nan)])
        self._w = np.concatenate([self._w, np.zeros(grow)])
        self._label = np.concatenate([self._label, np.full(grow, NOISE, dtype=int)])
        self._used = np.concatenate([self._used, np.zeros(grow, dtype=bool)])
        return int(self._used.size - grow)

    def _put(
        self, slot: int, z: np.ndarray, t_s: float, label: int, weight: float, v: float
    ) -> None:
        if not self._x.flags.writeable:  # shared with a copy (``__deepcopy__``)
            self._x = self._x.copy()
        self._x[slot] = z
        self._t[slot] = t_s
        self._v[slot] = v
        self._w[slot] = weight
        self._label[slot] = label
        self._used[slot] = True

    def _reservoir_capacity(self) -> int:
        n_active = sum(1 for r in self._records.values() if r.active)
        return max(self.params.min_reservoir, self._capacity // max(1, n_active))

    def _store_in_context(self, z: np.ndarray, t_s: float, v: float, context_id: int) -> None:
        """Algorithm R: a uniform sample of all frames ever assigned to the context."""
        self._count[context_id] = self._count.get(context_id, 0.0) + 1.0
        slots = np.flatnonzero(self._used & (self._label == context_id))
        if slots.size < self._reservoir_capacity():
            self._put(self._free_slot(), z, t_s, context_id, 1.0, v)
            return
        rng = self._rng.generator()
        if rng.random() * self._count[context_id] < slots.size:
            self._put(int(slots[rng.integers(slots.size)]), z, t_s, context_id, 1.0, v)

    def _store_noise(self, z: np.ndarray, t_s: float, v: float) -> None:
        """First-in-first-out window of the newest unclustered frames."""
        slots = np.flatnonzero(self._used & (self._label == NOISE))
        if slots.size >= self.params.noise_capacity:
            slot = int(slots[self._t[slots].argmin()])
        else:
            slot = self._free_slot()
        self._put(slot, z, t_s, NOISE, 1.0, v)

    # ----------------------------------------------------------------------------------------
    # Re-clustering
    def recent_noise_frames(self, t_s: float, window_s: float) -> int:
        """Noise frames taken in (``t_s - window_s``, ``t_s``] that are still in the store.

        The noise window keeps the newest ``noise_memory_s`` of them, so for a window shorter
        than that this is every noise frame of the window."""
        noise = self._used & (self._label == NOISE)
        return int(np.count_nonzero(noise & (self._t > t_s - window_s) & (self._t <= t_s)))

    def novelty_due(self, t_s: float) -> bool:
        """True when a novelty-triggered re-clustering is due at ``t_s`` [s].

        ``params.novelty_window_s`` None: never. Otherwise: at least ``params.novelty_frames``
        noise frames in the last ``novelty_window_s`` (a terrain never seen before, gathering
        at the camera rate) and ``novelty_min_interval_s`` since the latest re-clustering or
        triggered attempt.
        """
        p = self.params
        need = p.novelty_frames
        if need is None:
            return False
        for last in (self._recluster_time_s, self._novelty_try_s):
            if math.isfinite(last) and t_s - last < p.novelty_min_interval_s:
                return False
        return self.recent_noise_frames(t_s, p.novelty_window_s) >= need

    @property
    def novelty_counts(self) -> tuple[int, int]:
        """(triggered attempts, attempts kept) of :meth:`recluster_if_novel` so far."""
        return self._n_novelty_tries, self._n_novelty_kept

    def recluster_if_novel(self, t_s: float) -> bool:
        """A triggered re-clustering, kept only if it names a context not active before.

        It runs on a copy; the copy replaces this clusterer only if a new context appeared (a
        fresh id, or a vanished one back). Otherwise nothing changes (store, table, label
        version): the recent noise frames of a new terrain are not yet dense enough to stand on
        their own, and a clustering that merged them into a neighbouring context would widen
        its gate over the new terrain until the next periodic re-clustering splits them. The
        attempt counts for the rate limit either way.

        Returns:
            True if the re-clustering was kept.
        """
        self._novelty_try_s = float(t_s)
        self._n_novelty_tries += 1
        before = {k for k, r in self._records.items() if r.active}
        trial = copy.deepcopy(self)
        trial.recluster(t_s)
        after = {k for k, r in trial._records.items() if r.active}
        if not after - before:
            self._last_recluster_duration_s = trial._last_recluster_duration_s
            return False
        trial._n_novelty_kept += 1
        self.__dict__.update(trial.__dict__)
        return True

    def assign_frame(
        self, z: np.ndarray, t_s: float, speed_mps: float | None = None
    ) -> tuple[int, bool]:
        """A camera frame as the clustering system handles it: :meth:`assign` (the car at
        ``speed_mps`` [m/s], None: unknown), and where the
        frame is noise and the novelty trigger is due (:meth:`novelty_due`), a triggered
        re-clustering (:meth:`recluster_if_novel`) whose kept result names the frame anew.

        Returns:
            (the frame's context id, whether a triggered re-clustering was kept).
        """
        context_id = self.assign(z, t_s, speed_mps)
        if context_id == NOISE and self.novelty_due(t_s) and self.recluster_if_novel(t_s):
            self._visit = int(self.predict(z)[0])
            self._left = False
            return self._visit, True
        return context_id, False

    def recluster(self, t_s: float) -> ClusterTable:
        """Re-cluster the store with HDBSCAN, keep ids by Algorithm 1, rebuild strata and gates.

        Args:
            t_s: sim time of this re-clustering [s] (recorded in the table).

        Returns:
            The new cluster table.
        """
        start = time.perf_counter()
        # Small matrices: one BLAS thread is faster, and avoids contention with other processes.
        with one_blas_thread():
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
        if raw.max(initial=NOISE) < 0 and slots.size >= max(p.min_cluster_size, p.min_samples + 1):
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
        labels = fit_hdbscan(x, p.min_cluster_size, p.min_samples, allow_single_cluster=True)
        if labels.max(initial=NOISE) != 0:
            return labels
        for _ in range(10):
            members = labels == 0
            grown = GateIndex(x[members], labels[members], p).labels(x)
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
                chosen = self._rng.generator().choice(members.size, size=cap, replace=False, p=prob)
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
        self._index = GateIndex(self._x[members], self._label[members], self.params)
        labels, speeds = self._label[members], self._v[members]
        self._member_speed = {
            int(cid): float(speeds[labels == cid].max()) for cid in np.unique(labels)
        }  # NaN where a member's speed is unknown (max propagates it)

    def _finish_recluster(self, t_s: float, start: float) -> None:
        self._recluster_time_s = float(t_s)
        self._n_reclusterings += 1
        self._last_recluster_duration_s = time.perf_counter() - start
