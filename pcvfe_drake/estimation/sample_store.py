"""One time-ordered store of fitting samples, each with a context label that can change.

The context fitter's data (paper eq. 5d): samples (t, state, input) at the data rate, each
labelled with a context id (-1: noise/unknown). Labels are not final: after a re-clustering the
samples are relabelled with the clusters as they now stand (:func:`labels_from_frames`), so the
frames that were noise while a terrain was new join its context.

:class:`SampleStore` keeps the rows in time order in fixed-size chunks. Drake copies the fitter's
abstract state at every update, so a copy must be cheap: full chunks (rows and labels) are
read-only and shared between copies; only the partly filled tail is copied. Relabelling replaces
the label array of each chunk that changes (never writes into a shared one). Memory is bounded by
:meth:`SampleStore.retain`: each label keeps its newest ``capacity`` rows.

Core: numpy only.
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.shallow_copy import shallow_copy
from pcvfe_drake.vehicle.single_track import NU, NX

ROW = 1 + NX + NU
"""Numbers per row: t [s], state (7, project order), input [steer_rate rad/s, accel m/s^2]
applied from the row's time to the next row's (:meth:`SampleStore.append`)."""
NOISE = -1
TIME_TOL_S = 1e-6
"""Tolerance on time comparisons [s] (sample and frame times from different periodic events)."""


def inputs_as_read(inputs: np.ndarray) -> np.ndarray:
    """The inputs a simulation's samples read along a drive whose row k holds the input applied
    from t_k on (a drive log's convention): each sample reads the input applied before its
    instant, the previous row's (the first row its own). :meth:`SampleStore.append` turns
    such readings back into the drive's inputs."""
    inputs = np.asarray(inputs, dtype=float)
    return np.vstack([inputs[:1], inputs[:-1]])


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


class SampleStore:
    """Append-only, time-ordered rows of (t, state (7), input (2)) with an int label per row.

    Rows are stored in chunks of ``chunk_size``; full chunks and their label arrays are read-only
    and shared between copies (``copy.deepcopy`` copies only the partly filled tail).
    """

    def __init__(self, chunk_size: int = 100) -> None:
        if chunk_size < 1:
            raise ValueError(f"SampleStore: chunk_size must be >= 1, got {chunk_size}")
        self.chunk_size = int(chunk_size)
        self._chunks: tuple[np.ndarray, ...] = ()
        self._labels: tuple[np.ndarray, ...] = ()
        self._tail = np.empty((self.chunk_size, ROW))
        self._tail_labels = np.empty(self.chunk_size, dtype=int)
        self._tail_n = 0

    def append(self, t: float, state: np.ndarray, inputs: np.ndarray, label: int) -> None:
        """Add a row; ``t`` must not be earlier than the last row's (time order).

        ``inputs`` is the input read at ``t``. A controller's held output read at a sample
        instant is the one applied *before* it: the sample's update and the controller's
        update at the same instant both read the state from before either (Drake's discrete
        updates; a replay's ``actuation_before`` and the UKF's predict read it alike). So it is
        the input applied since the previous sample: the previous row takes it as the input
        applied from that row on, and this row holds it until the next sample brings the
        input applied from ``t`` (the newest row's input starts no rollout: a window's last
        state has no step after it)."""
        if self._tail_n:
            self._tail[self._tail_n - 1, 1 + NX :] = inputs
        elif self._chunks:  # the previous row closed a shared read-only chunk: copy that one
            last = self._chunks[-1].copy()
            last[-1, 1 + NX :] = inputs
            self._chunks = (*self._chunks[:-1], _read_only(last))
        row = self._tail[self._tail_n]
        row[0] = t
        row[1 : 1 + NX] = state
        row[1 + NX :] = inputs
        self._tail_labels[self._tail_n] = label
        self._tail_n += 1
        if self._tail_n == self.chunk_size:
            self._chunks = (*self._chunks, _read_only(self._tail))
            self._labels = (*self._labels, _read_only(self._tail_labels))
            self._tail = np.empty((self.chunk_size, ROW))
            self._tail_labels = np.empty(self.chunk_size, dtype=int)
            self._tail_n = 0

    def __len__(self) -> int:
        return len(self._chunks) * self.chunk_size + self._tail_n

    def labels(self) -> np.ndarray:
        """(N,) labels of all rows, oldest first (a new array)."""
        return np.concatenate([*self._labels, self._tail_labels[: self._tail_n]])

    def times(self) -> np.ndarray:
        """(N,) times of all rows [s], oldest first (a new array)."""
        return np.concatenate([*(c[:, 0] for c in self._chunks), self._tail[: self._tail_n, 0]])

    def rows(self, index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(t (M,), states (M, 7), inputs (M, 2))`` of the rows ``index`` (default all).

        ``index``: increasing row numbers (as from ``np.flatnonzero(store.labels() == k)``).
        """
        rows = np.concatenate([*self._chunks, self._tail[: self._tail_n]], axis=0)
        if index is not None:
            rows = rows[index]
        return rows[:, 0], rows[:, 1 : 1 + NX], rows[:, 1 + NX :]

    def set_labels(self, labels: np.ndarray) -> int:
        """Replace every row's label; returns the number of rows whose label changed.

        Chunks whose labels do not change keep their (shared) array.
        """
        labels = np.asarray(labels, dtype=int)
        if labels.shape != (len(self),):
            raise ValueError(
                f"SampleStore.set_labels: expected {len(self)} labels, got shape {labels.shape}"
            )
        changed = 0
        new_chunks = []
        for i, old in enumerate(self._labels):
            new = labels[i * self.chunk_size : (i + 1) * self.chunk_size]
            diff = int(np.count_nonzero(new != old))
            changed += diff
            new_chunks.append(_read_only(new.copy()) if diff else old)
        self._labels = tuple(new_chunks)
        tail = labels[len(self._labels) * self.chunk_size :]
        changed += int(np.count_nonzero(tail != self._tail_labels[: self._tail_n]))
        self._tail_labels = self._tail_labels.copy()  # never write into a copy's array
        self._tail_labels[: self._tail_n] = tail
        return changed

    def retain(self, capacity: int) -> int:
        """Keep each label's newest ``capacity`` rows (time order kept); returns rows dropped.

        Rebuilds the chunks (O(N)): call it when the store has outgrown its budget, not per row.
        """
        labels = self.labels()
        keep = np.ones(labels.size, dtype=bool)
        for label in np.unique(labels):
            rows = np.flatnonzero(labels == label)
            keep[rows[: max(0, rows.size - capacity)]] = False
        dropped = int(labels.size - keep.sum())
        if dropped == 0:
            return 0
        everything = np.concatenate([*self._chunks, self._tail[: self._tail_n]], axis=0)[keep]
        labels = labels[keep]
        n_full = labels.size // self.chunk_size
        cs = self.chunk_size
        blocks = [slice(i * cs, (i + 1) * cs) for i in range(n_full)]
        self._chunks = tuple(_read_only(everything[b].copy()) for b in blocks)
        self._labels = tuple(_read_only(labels[b].copy()) for b in blocks)
        self._tail = np.empty((cs, ROW))
        self._tail_labels = np.empty(cs, dtype=int)
        self._tail_n = labels.size - n_full * cs
        self._tail[: self._tail_n] = everything[n_full * cs :]
        self._tail_labels[: self._tail_n] = labels[n_full * cs :]
        return dropped

    def __deepcopy__(self, memo) -> SampleStore:
        other = shallow_copy(self)
        other._tail = self._tail.copy()
        other._tail_labels = self._tail_labels.copy()
        return other


def labels_from_frames(
    t: np.ndarray,
    labels: np.ndarray,
    frame_t: np.ndarray,
    frame_labels: np.ndarray,
    frame_period_s: float,
) -> np.ndarray:
    """Samples' labels as the clustering now stands: each takes the label of its frame.

    A sample at time ``t`` is covered by the latest frame taken before it (``t_f < t``) if that
    frame is at most one ``frame_period_s`` older (the clustering's context id is a zero-order
    hold of the frames; a sample taken at the same instant as a frame still reads the previous
    one). Covered samples take their frame's label, noise included. Samples whose frame is no
    longer stored (the clusterer keeps a bounded sample of each context's frames) keep their
    label, unless most of the covered samples of that label moved to one other context (a merge
    or a renaming): then they follow. Noise samples without a frame stay noise.

    Args:
        t: (N,) sample times [s], increasing.
        labels: (N,) their current labels (-1 noise).
        frame_t: (M,) frame times [s] (any order).
        frame_labels: (M,) the frames' labels.
        frame_period_s: the camera period [s].

    Returns:
        (N,) int: the new labels.
    """
    t = np.asarray(t, dtype=float)
    labels = np.asarray(labels, dtype=int)
    new = labels.copy()
    frame_t = np.asarray(frame_t, dtype=float)
    if t.size == 0 or frame_t.size == 0:
        return new
    order = np.argsort(frame_t, kind="stable")
    ft = frame_t[order]
    fl = np.asarray(frame_labels, dtype=int)[order]
    j = np.searchsorted(ft, t - TIME_TOL_S, side="left") - 1
    jj = np.maximum(j, 0)
    covered = (j >= 0) & (t - ft[jj] <= frame_period_s + TIME_TOL_S)
    new[covered] = fl[jj[covered]]
    for old in np.unique(labels[covered & (labels >= 0)]):
        of_old = labels == old
        moved_to, counts = np.unique(new[covered & of_old], return_counts=True)
        best = int(moved_to[counts.argmax()])
        if best >= 0 and best != old and 2 * counts.max() > counts.sum():
            new[of_old & ~covered] = best
    return new


def visit_members(
    labels: np.ndarray, times: np.ndarray, ident: int, noise_hold_s: float
) -> np.ndarray:
    """(N,) mask of the samples that belong to context ``ident``'s visits: its own samples and
    the noise samples of each spell that left it and came back to it within ``noise_hold_s``
    [s] (from the spell's first sample to the context's next; the handing's visit rule,
    ``handing.visit_tracker``: such a spell is no switch, so its samples are the visit's).

    Why: the online clustering calls a frame noise where it is not sure, also in the middle of
    a terrain it knows, and a window of the fit never spans a sample of another label; noise
    frames every half second leave a context no window of its horizon until a re-clustering
    gives them its label (up to ten seconds later). A spell that does not return to the same
    context within the hold (a new terrain, a transition) stays noise.

    ``labels``, ``times``: the store's labels and times in time order.
    """
    labels = np.asarray(labels)
    mine = labels == ident
    noise = labels == NOISE
    if not (noise.any() and mine.any() and noise_hold_s > 0):
        return mine
    edges = np.diff(noise.astype(np.int8))
    first = np.flatnonzero(edges == 1) + 1  # a spell's first sample (not the store's first)
    last = np.flatnonzero(edges == -1)  # a spell's last sample (not the store's last)
    if noise[0]:
        last = last[1:]
    if noise[-1]:
        first = first[:-1]
    times = np.asarray(times, dtype=float)
    held = (
        (labels[first - 1] == ident)
        & (labels[last + 1] == ident)
        & (times[last + 1] - times[first] <= noise_hold_s + TIME_TOL_S)
    )
    if held.any():
        mine |= ranges_mask(labels.size, first[held], last[held])
    return mine


def ranges_mask(n: int, first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """(n,) mask of the indices in the ranges ``first[i] .. last[i]`` (both ends included; a
    range may overlap others and run past ``n - 1``)."""
    first = np.asarray(first, dtype=np.int64)
    marks = np.zeros(n + 1, dtype=np.int64)
    np.add.at(marks, first, 1)
    np.add.at(marks, np.minimum(np.asarray(last, dtype=np.int64) + 1, n), -1)
    return np.cumsum(marks[:-1]) > 0
