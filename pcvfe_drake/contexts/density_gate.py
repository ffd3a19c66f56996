"""Density tools of the context clustering: HDBSCAN labels, k-th-neighbour distances, the
outlier gate of a context, and the detachment of small groups from a cluster.

:class:`GateIndex` labels vectors by gated k-nearest-neighbour search over the stored members of
the active contexts (see :class:`pcvfe_drake.contexts.clustering.ContextClusterer`).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from sklearn.cluster import HDBSCAN

from pcvfe_drake.contexts.clustering_params import NOISE, ClusteringParams


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
    return fit_hdbscan(x, min_cluster_size, min_samples, allow_single_cluster=False)


def fit_hdbscan(
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


def kth_member_distances(members: np.ndarray, k: int) -> np.ndarray:
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


def gate_radius(kth: np.ndarray, params: ClusteringParams, scale_sq: float) -> float:
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
        gate = gate_radius(kth, params, float(sq.max()))
        n_comp, comp = connected_components(csr_matrix(d2 <= gate * gate), directed=False)
        if n_comp == 1:
            continue
        mass = np.bincount(comp, weights=weights[idx], minlength=n_comp)
        small = mass[comp] < params.min_cluster_size
        out[idx[small]] = NOISE
    return out


class GateIndex:
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
            kth = kth_member_distances(self.x[s:e], self.k)
            gate = gate_radius(kth, params, float(self.sq[s:e].max()))
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

    def within(self, z: np.ndarray, cid: int, scale: float) -> bool:
        """True if vector ``z`` (d,) is nearest to a member of context ``cid`` and passes its
        gate widened ``scale`` times (its k-th nearest member of ``cid`` within ``scale`` times
        the gate). False for a context without members here."""
        if int(cid) not in self.bounds:
            return False
        d2 = self.sq - 2.0 * (self.x @ z) + float(z @ z)
        if self.ids[d2.argmin()] != cid:
            return False
        s, e = self.bounds[int(cid)]
        kk = min(self.k, e - s)
        kth = np.partition(d2[s:e], kk - 1)[kk - 1]
        return bool(kth <= scale * scale * self.gate_sq[int(cid)])


def full_hdbscan_labels(x: np.ndarray, params: ClusteringParams | None = None) -> np.ndarray:
    """Reference labels: HDBSCAN over all of ``x`` with the clusterer's parameters.

    What the paper does every 10 s (cost grows like N^2); used to measure how faithful the bounded
    scheme is. Ids are HDBSCAN's own labels (not persistent).
    """
    p = params if params is not None else ClusteringParams()
    return hdbscan_labels(np.asarray(x, dtype=float), p.min_cluster_size, p.min_samples)
