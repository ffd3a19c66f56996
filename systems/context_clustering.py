"""ContextClustering: zero-shot terrain contexts from information vectors z(t) (paper IV-A)."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, Context, EventStatus, LeafSystem, State

from pcvfe_drake.contexts.clustering import (
    NOISE,
    ClusteringParams,
    ClusterTable,
    ContextClusterer,
    FrameLabels,
    StoredFeatures,
)
from pcvfe_drake.vehicle.single_track import NX, V


class ContextClustering(LeafSystem):
    """Assigns every camera frame a terrain context id; re-clusters with HDBSCAN every 10 s (and,
    optionally, as soon as a new terrain has gathered enough frames).

    .. pydrake_system::

        name: ContextClustering
        input_ports:
        - features
        - state (optional)
        output_ports:
        - context_id
        - cluster_table
        - stored_features
        - frame_labels

    - ``features``: vector of ``feature_dim`` numbers, z(t) from ClipFeatures (any backend).
    - ``state`` (optional): the measured single-track state (7-vector, SI units); its speed
      tells whether the camera's motion blur can explain a frame that continues a visit
      beyond its context's gate (``ContextClusterer.assign``, docs/clustering.md, "Continuing
      a visit"). Left unconnected, the speed is unknown and no frame is judged by it.
    - ``context_id``: 1-element vector, the current context id (an integer; -1 = noise or a
      terrain not seen before). From state: a zero-order hold at the frame rate, no feedthrough.
    - ``cluster_table``: abstract :class:`pcvfe_drake.contexts.clustering.ClusterTable` (id,
    centroid,
      size, first/last seen time of every context, vanished ones included).
    - ``stored_features``: abstract :class:`pcvfe_drake.contexts.clustering.StoredFeatures`, a
      copy of the bounded store (vectors, labels, times) for views; copied only when evaluated.
    - ``frame_labels``: abstract :class:`pcvfe_drake.contexts.clustering.FrameLabels`, the stored
      frames' times and current labels, time-ordered, with the label version (re-clusterings so
      far) and the frame period: what a consumer (the ContextFitter) needs to relabel its own
      samples after a re-clustering (paper eq. 5d). No feature vectors; copied when evaluated.

    Rates: a periodic unrestricted update every ``frame_period_s`` (default 1 / frame rate of
    ``params``, 0.1 s), at ``frame_offset_s`` after each period start (default 0), reads
    ``features`` and assigns and stores the frame at once; a periodic unrestricted update every
    ``recluster_period_s`` (default 10 s = 0.1 Hz, first at t = 10 s) re-clusters and keeps ids
    by centroid persistence (paper Algorithm 1). When both fire at the same time the frame is
    taken first. A camera that updates its image at offset 0 is read one period late by a frame
    event at offset 0 (simultaneous updates read the state before the step); a small
    ``frame_offset_s`` (e.g. 1 ms) assigns each frame in the same period it was taken. The
    :class:`ContextClusterer` (store, table, random generator) lives in the context's abstract
    state. A frame with non-finite features gets -1
    and is not stored.

    Novelty trigger (``params.novelty_window_s`` set; off by default, the paper's design): when
    a noise frame finds the recent frames mostly noise (:meth:`ContextClusterer.novelty_due`: a
    terrain not seen before has gathered enough frames to form a context), the frame event
    tries a re-clustering at once (:meth:`ContextClusterer.recluster_if_novel`: kept only if it
    names a new context), rate-limited by ``params.novelty_min_interval_s``; if kept, the frame
    takes its id from the new clustering, ids persist and ``frame_labels`` gets a new version
    exactly as after a periodic re-clustering. The periodic one keeps running.
    """

    def __init__(
        self,
        feature_dim: int = 36,
        params: ClusteringParams | None = None,
        *,
        frame_period_s: float | None = None,
        recluster_period_s: float = 10.0,
        frame_offset_s: float = 0.0,
    ) -> None:
        super().__init__()
        if not (isinstance(feature_dim, int | np.integer) and feature_dim >= 1):
            raise ValueError(f"feature_dim must be a positive int, got {feature_dim!r}")
        self._params = params if params is not None else ClusteringParams()
        if frame_period_s is None:
            frame_period_s = 1.0 / self._params.frame_rate_hz
        for name, value in (
            ("frame_period_s", frame_period_s),
            ("recluster_period_s", recluster_period_s),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
        if not (math.isfinite(frame_offset_s) and 0.0 <= frame_offset_s < frame_period_s):
            raise ValueError(
                f"frame_offset_s must be in [0, frame_period_s={frame_period_s}) s, "
                f"got {frame_offset_s!r}"
            )
        self._feature_dim = int(feature_dim)
        self._frame_offset_s = float(frame_offset_s)
        self._frame_period_s = float(frame_period_s)
        self._recluster_period_s = float(recluster_period_s)

        self._features_port = self.DeclareVectorInputPort("features", self._feature_dim)
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._clusterer_index = self.DeclareAbstractState(
            AbstractValue.Make(ContextClusterer(self._params))
        )
        self._id_index = self.DeclareDiscreteState(BasicVector([float(NOISE)]))
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self._frame_period_s,
            offset_sec=self._frame_offset_s,
            update=self._on_frame,
        )
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self._recluster_period_s,
            offset_sec=self._recluster_period_s,
            update=self._on_recluster,
        )
        self._context_id_port = self.DeclareStateOutputPort("context_id", self._id_index)
        self._table_port = self.DeclareAbstractOutputPort(
            "cluster_table",
            lambda: AbstractValue.Make(ClusterTable()),
            self._calc_table,
            prerequisites_of_calc={self.abstract_state_ticket(self._clusterer_index)},
        )
        self._stored_port = self.DeclareAbstractOutputPort(
            "stored_features",
            lambda: AbstractValue.Make(StoredFeatures()),
            self._calc_stored,
            prerequisites_of_calc={self.abstract_state_ticket(self._clusterer_index)},
        )
        self._frame_labels_port = self.DeclareAbstractOutputPort(
            "frame_labels",
            lambda: AbstractValue.Make(FrameLabels()),
            self._calc_frame_labels,
            prerequisites_of_calc={self.abstract_state_ticket(self._clusterer_index)},
        )

    @property
    def params(self) -> ClusteringParams:
        """The clustering parameters."""
        return self._params

    @property
    def frame_period_s(self) -> float:
        """Period of the per-frame assignment [s]."""
        return self._frame_period_s

    @property
    def frame_offset_s(self) -> float:
        """Offset of the per-frame assignment within its period [s]."""
        return self._frame_offset_s

    @property
    def recluster_period_s(self) -> float:
        """Period of the HDBSCAN re-clustering [s]."""
        return self._recluster_period_s

    def clusterer(self, context: Context) -> ContextClusterer:
        """The clusterer held in ``context`` (read only: change it through events)."""
        return context.get_abstract_state(self._clusterer_index).get_value()

    def _on_frame(self, context: Context, state: State) -> EventStatus:
        z = np.asarray(self._features_port.Eval(context), dtype=float)
        clusterer = state.get_mutable_abstract_state(self._clusterer_index).get_mutable_value()
        speed = None
        if self._state_port.HasValue(context):
            speed = float(self._state_port.Eval(context)[V])
        context_id, _ = clusterer.assign_frame(z, context.get_time(), speed)
        state.get_mutable_discrete_state(self._id_index).SetAtIndex(0, float(context_id))
        return EventStatus.Succeeded()

    def _on_recluster(self, context: Context, state: State) -> EventStatus:
        clusterer = state.get_mutable_abstract_state(self._clusterer_index).get_mutable_value()
        clusterer.recluster(context.get_time())
        return EventStatus.Succeeded()

    def _calc_table(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self.clusterer(context).table())

    def _calc_stored(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self.clusterer(context).stored())

    def _calc_frame_labels(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self.clusterer(context).frame_labels(self._frame_period_s))
