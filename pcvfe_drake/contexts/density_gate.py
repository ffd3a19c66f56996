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
from scipy.sparse.csgraph import connected_components, depth_first_order
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


def _kth_smallest(d2: np.ndarray, k: int) -> np.ndarray:
    """The k-th smallest entry (1-based) of each row of ``d2``."""
    return np.partition(d2, k - 1, axis=1)[:, k - 1]


def _scaled_quantile(kth: np.ndarray, params: ClusteringParams) -> float:
    """``gate_scale`` times the ``gate_quantile`` of the k-th-neighbour distances ``kth``: the
    outlier gate without its rounding floor.

    Of M distances the quantile is taken at ``min(gate_quantile, 1 - (k - 1) / M)``, k =
    ``gate_neighbours``: the k - 1 largest never set the gate. Of fewer than about 100 members
    the high quantile is the largest one or two values, so a lone stray (a frame of another
    terrain that a re-clustering joined) would set the gate and open it to its terrain; a group
    of fewer than k members cannot pass a frame by nearness (:func:`detach_pockets` keeps them as
    members), and now not by the width it gives the gate either. From ``(k - 1) / (1 -
    gate_quantile)`` members on (200) it is the plain quantile."""
    m = kth.size
    q = params.gate_quantile
    if m:
        q = max(0.0, min(q, 1.0 - (params.gate_neighbours - 1) / m))
    return params.gate_scale * float(np.quantile(kth, q))


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
        out[s : s + block] = _kth_smallest(d2, k)
    return np.sqrt(np.maximum(out, 0.0))


def gate_radius(kth: np.ndarray, params: ClusteringParams, scale_sq: float) -> float:
    """Gate of a context from its members' k-th-neighbour distances (with a rounding floor)."""
    gate = _scaled_quantile(kth, params) if kth.size else 0.0
    return max(gate, 1e-6 * (1.0 + math.sqrt(scale_sq)))


def detach_small_groups(
    x: np.ndarray, labels: np.ndarray, weights: np.ndarray, params: ClusteringParams
) -> np.ndarray:
    """Labels with the members of each cluster that are not connected to its body set to noise.

    HDBSCAN counts a group of fewer than ``min_cluster_size`` points that splits off a selected
    cluster as members of that cluster: the first frames of a new terrain next to a known one
    join the known context, and the outlier gate would then pass the new terrain's frames. Within
    each cluster, members are linked when closer than the cluster's gate; linked groups that
    stand for fewer than ``min_cluster_size`` frames (sum of weights) become noise. Such a group
    also widens the gate it is judged by (its sparse members set the gate's high quantile), so a
    group can stay linked only through its own width: :func:`detach_pockets` then removes the
    groups that lie beyond the gate the rest of the cluster has without them.
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
        kth = np.sqrt(_kth_smallest(d2, kk))
        gate = gate_radius(kth, params, float(sq.max()))
        n_comp, comp = connected_components(csr_matrix(d2 <= gate * gate), directed=False)
        keep = np.ones(idx.size, dtype=bool)
        if n_comp > 1:
            mass = np.bincount(comp, weights=weights[idx], minlength=n_comp)
            keep = mass[comp] >= params.min_cluster_size
        alive = np.flatnonzero(keep)
        sub = d2 if keep.all() else d2[np.ix_(alive, alive)]
        pocket = detach_pockets(sub, weights[idx[alive]], params)
        keep[alive[pocket]] = False
        out[idx[~keep]] = NOISE
    return out


def _reach_sq(d2: np.ndarray, core: np.ndarray) -> np.ndarray:
    """Squared mutual reachability distances of ``d2`` (squared distances, diagonal inf) with
    ``core`` (each point's squared leave-one-out k-th-neighbour distance) as core distances."""
    return np.maximum(d2, np.maximum(core[:, None], core[None, :]))


def _spanning_tree(r2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum spanning tree of the complete graph with weights ``r2`` (M, M; the diagonal is
    ignored), by Prim's algorithm (dense: M steps of O(M)): the two ends and the weight of each
    of its ``M - 1`` edges."""
    n = r2.shape[0]
    done = np.zeros(n, dtype=bool)
    done[0] = True
    best = r2[0].copy()
    best[0] = np.inf
    parent = np.zeros(n, dtype=int)
    child = np.empty(n - 1, dtype=int)
    via = np.empty(n - 1, dtype=int)
    weight = np.empty(n - 1)
    for e in range(n - 1):
        j = int(best.argmin())
        child[e], via[e], weight[e] = j, parent[j], best[j]
        done[j] = True
        best[j] = np.inf
        row = r2[j]
        closer = (row < best) & ~done
        best[closer] = row[closer]
        parent[closer] = j
    return child, via, weight


def _components(n: int, ends: tuple[np.ndarray, np.ndarray], linked: np.ndarray) -> np.ndarray:
    """Component label of each of ``n`` points under the tree edges ``ends`` where ``linked``."""
    a, b = ends[0][linked], ends[1][linked]
    graph = csr_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _subtrees(n: int, ends: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """For a tree of ``n`` points rooted at point 0: the end of each edge farther from the root,
    and each point's (first, last) position in a depth-first order, (n, 2): the points below an
    edge are those whose position lies within its far end's first and last."""
    graph = csr_matrix((np.ones(len(ends[0])), ends), shape=(n, n))
    order, parent = depth_first_order(graph, 0, directed=False, return_predecessors=True)
    size = np.ones(n, dtype=int)
    for node in order[:0:-1]:
        size[parent[node]] += size[node]
    first = np.empty(n, dtype=int)
    first[order] = np.arange(n)
    span = np.stack([first, first + size - 1], axis=1)
    far = np.where(parent[ends[0]] == ends[1], ends[0], ends[1])
    return far, span


def _gate_of(d2: np.ndarray, rows: np.ndarray, params: ClusteringParams) -> float:
    """Outlier gate (without the rounding floor) of the points ``rows`` of ``d2`` (squared
    distances, diagonal inf) among themselves."""
    k = min(params.gate_neighbours, rows.size - 1)
    return _scaled_quantile(np.sqrt(_kth_smallest(d2[np.ix_(rows, rows)], k)), params)


def detach_pockets(d2: np.ndarray, weights: np.ndarray, params: ClusteringParams) -> np.ndarray:
    """(M,) bool: the members of one cluster that form pockets, given their squared pairwise
    distances ``d2`` (M, M; diagonal inf) and weights (M,).

    The members are linked as HDBSCAN links points, by the minimum spanning tree of their
    mutual reachability distances, here with the gate's own k (``gate_neighbours``): two members
    are as far apart as the larger of their distance and their k-th-neighbour distances, the
    density a new frame must meet at the gate. An edge of the tree parts the lighter side from
    the rest; the side is separated when the edge is longer than the gate the rest has without
    it, so the side's own sparse members, which widen the whole cluster's gate, cannot keep it
    linked. A separated side of at least ``gate_neighbours`` members (enough to pass a frame by
    themselves) is a pocket where it stands for fewer than ``min_cluster_size`` frames: HDBSCAN
    could not make a cluster of it and kept it as members. A heavier side that falls apart at
    the rest's gate into several groups of at least ``gate_neighbours`` members loses those
    lighter than ``min_cluster_size``, so that several foreign groups, each small and far from
    the others, do not pass as one lobe; a side that stays one group (a lobe HDBSCAN kept) and
    a group as heavy as a cluster stay. Members off the body alone or in pairs stay: they
    cannot pass a frame by themselves. A cluster without a pocket keeps every member, so its
    gate is exactly the one its members give. Edges are tried longest first; after each pocket
    the remaining edges are tried again against the smaller rest.
    """
    m = d2.shape[0]
    pocket = np.zeros(m, dtype=bool)
    k = min(params.gate_neighbours, m - 1)
    if k < 1 or m <= params.gate_neighbours:
        return pocket
    core = _kth_smallest(d2, k)
    child, via, weight = _spanning_tree(_reach_sq(d2, core))
    order = np.argsort(weight)[::-1]
    kth = np.sqrt(core)
    ends = (child, via)
    far, span = _subtrees(m, ends)
    mcs = params.min_cluster_size
    while True:
        total = float(weights[~pocket].sum())
        if total < mcs:
            return pocket
        # Dropping members can only lengthen the others' k-th-neighbour distances, so a rest's
        # gate is at least the one of its members' distances as they are now (``bound``).
        # The lighter side leaves at least half the weight: a floor for every rest's gate.
        n = int((~pocket).sum())
        half = int((np.cumsum(np.sort(weights[~pocket])) <= total / 2).sum())
        least = np.sort(kth[~pocket])[: max(1, n - half)]
        floor = _scaled_quantile(least, params)
        live = ~pocket[child] & ~pocket[via]
        found = None
        for e in order:
            if weight[e] <= floor * floor:
                break
            if not live[e]:
                continue
            lo, hi = span[far[e]]
            side = (span[:, 0] >= lo) & (span[:, 0] <= hi) & ~pocket
            mass = float(weights[side].sum())
            small = side if mass <= total - mass else ~side & ~pocket
            rest = ~small & ~pocket
            if small.sum() < params.gate_neighbours or weights[rest].sum() < mcs:
                continue
            bound = _scaled_quantile(kth[rest], params)
            if weight[e] <= bound * bound:
                continue
            gate = _gate_of(d2, np.flatnonzero(rest), params)
            if weight[e] <= gate * gate:
                continue
            if weights[small].sum() >= mcs:
                cut = live & (weight <= gate * gate)
                cut[e] = False
                pieces = _components(m, ends, cut)
                count = np.bincount(pieces[small], minlength=m)
                group = count >= params.gate_neighbours
                if group.sum() < 2:
                    continue  # one group, with stragglers at most: a lobe
                light = np.bincount(pieces[small], weights[small], minlength=m) < mcs
                small = small & (group & light)[pieces]
                if not small.any():
                    continue
            found = small
            break
        if found is None:
            return pocket
        pocket |= found


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
            kth = _kth_smallest(d2[rows, s:e], kk)
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
