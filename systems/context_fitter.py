"""ContextFitter: context-specific friction estimation through the dynamics (paper IV-B)."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from copy import deepcopy
from dataclasses import dataclass, replace

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import (
    BasicVector,
    Context,
    EventStatus,
    InputPort,
    LeafSystem,
    State,
)

from pcvfe_drake.contexts.cluster_table import FrameLabels
from pcvfe_drake.estimation.context_estimator import ContextEstimator, EstimateTable
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.probe import DEFAULT_PROBE_USE_FRACTION
from pcvfe_drake.hardware.scheduling import normal_scheduling
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import NTHETA, NU, NX

_ROW = 1 + NX + NU + 2
"""A sample: time [s], state (NX), actuation (NU), context id, frame-labels version (-inf:
none)."""
_LAST_TAKEN, _NEXT_REFIT = 0, 1
"""The fitter's schedule (discrete state): time of the last sample the estimator took [s],
time of the next refit [s]."""
_TIME_EPS_S = 1e-9
"""Event times closer than this are the same time [s]."""


@dataclass(frozen=True)
class _SampleInputs:
    """The input ports a fitter's sample is read from, declared alike by the fitter and by
    :class:`HeldSamples` (state, actuation, context id, the optional frame labels)."""

    state: InputPort
    actuation: InputPort
    context_id: InputPort
    frame_labels: InputPort

    @staticmethod
    def declare(system: LeafSystem) -> _SampleInputs:
        return _SampleInputs(
            system.DeclareVectorInputPort("state", NX),
            system.DeclareVectorInputPort("actuation", NU),
            system.DeclareVectorInputPort("context_id", 1),
            system.DeclareAbstractInputPort("frame_labels", AbstractValue.Make(FrameLabels())),
        )

    def row(self, context: Context, relabel: bool) -> np.ndarray:
        """The sample at the context's time: (t, state, actuation, context id, frame-labels
        version; -inf without ``relabel`` or where the labels have no value)."""
        row = np.empty(_ROW)
        row[0] = context.get_time()
        row[1 : 1 + NX] = self.state.Eval(context)
        row[1 + NX : 1 + NX + NU] = self.actuation.Eval(context)
        row[1 + NX + NU] = self.context_id.Eval(context)[0]
        row[-1] = (
            self.frame_labels.Eval(context).version
            if relabel and self.frame_labels.HasValue(context)
            else -math.inf
        )
        return row


def samples_per_period(period_s, sample_period_s: float) -> int:
    """How many sampling periods make ``period_s`` (0 where it is not a whole multiple)."""
    ok = isinstance(period_s, int | float) and math.isfinite(period_s)
    per = round(period_s / sample_period_s) if ok else 0
    return per if per >= 1 and abs(per * sample_period_s - period_s) <= 1e-9 else 0


def _decision_period(decision_period_s, sample_period_s: float) -> tuple[float, int]:
    """``(decision period [s], samples per decision)``; a clear error unless it is a whole
    multiple of the sample period."""
    if decision_period_s is None:
        return sample_period_s, 1
    per = samples_per_period(decision_period_s, sample_period_s)
    if not per:
        raise ValueError(
            f"ContextFitter: decision_period_s must be a whole multiple of sample_period_s "
            f"({sample_period_s!r} s), got {decision_period_s!r}"
        )
    return float(decision_period_s), per


class ContextFitter(LeafSystem):
    """Estimates theta = [mu, C_Sf, C_Sr] per terrain context and outputs the current one.

    .. pydrake_system::

        name: ContextFitter
        input_ports:
        - state
        - actuation
        - context_id
        - frame_labels (optional)
        - held_samples (with a decision period longer than the sample period)
        output_ports:
        - theta_hat
        - estimate_table

    - ``state``: 7-vector, the ST state [sx, sy, delta, v, psi, psi_dot, beta] (SI units).
    - ``actuation``: 2-vector [steer_rate rad/s, accel m/s^2] applied to the vehicle.
    - ``context_id``: 1-vector, the terrain context (float-valued int; -1 = noise/unknown).
    - ``frame_labels`` (optional): abstract :class:`pcvfe_drake.contexts.cluster_table.FrameLabels`
      from ContextClustering: the stored frames' times and labels as the clustering now stands.
      When its version changes (a re-clustering), the next sample update relabels the stored
      samples (each takes the label of the frame covering its time, so the noise samples of a
      terrain that was new join its context; paper eq. 5d) and refits the contexts whose data
      changed at once (bounded like every refit), so a new terrain gets its first fit one
      sample period after the re-clustering instead of at the next refit update. Left
      unconnected (a station without clustering, or ids from elsewhere), or with
      ``relabel=False``, samples keep the id they were taken with.
    - ``theta_hat``: 3-vector [mu, C_Sf, C_Sr] for the current frame as the handing decides
      (``pcvfe_drake.handing``, ``docs/handing.md``), from state (zero-order hold at the sample
      rate, no direct feedthrough). Always finite.
    - ``estimate_table``: abstract :class:`pcvfe_drake.estimation.context_estimator.EstimateTable`:
    per
      context theta, standard deviations, samples, windows, last update time, status and the
      number of discarded (diverged) refits.

    Rates: the state, actuation and context id are sampled every ``sample_period_s`` (default
    0.01 s = 100 Hz) and appended to the sample store in time order; every ``period_s`` (default
    1 s = 1 Hz, first at t = ``period_s``) a refit of the contexts whose data changed starts, on
    the data up to then, published ``latency_s`` later (the declared latency, in simulated time:
    the NMPC never waits for a refit, and a seed still gives one result; 0: published at once),
    bounded per update (see :class:`pcvfe_drake.estimation.live_fit_config.LiveFitConfig`:
    ``max_contexts_per_update``, ``max_windows``, ``max_iterations``). At a time with both, the
    sample is taken first. The :class:`ContextEstimator` (sample store, estimates) lives in the
    context's abstract state.

    ``theta_hat`` is decided every ``decision_period_s`` (the period at which the controller
    reads it; default: every sample). With a longer decision period the samples in between come
    from a :class:`HeldSamples` system at the sample rate (input ``held_samples``), and one
    unrestricted update, half a sample period after the last sample before each of the
    controller's updates, hands them to the estimator one by one, in time order, with their own
    times: the estimator goes through the same steps as
    with a decision at every sample (a refit or relabelling due at a held sample happens at
    that sample's time, on the data up to it), and the controller, whose updates fall on the
    decision period's multiples, reads the same ``theta_hat``. What changes is the cost: Drake
    copies the whole state of a system at each of its unrestricted updates, here the estimator,
    twice per update; the held samples save those copies and the handing's decisions for the
    samples the controller never reads. :meth:`estimator` includes the held samples; the
    ``estimate_table`` output is the estimator's as of the last decision (no direct
    feedthrough).
    """

    def __init__(
        self,
        params: VehicleParams,
        *,
        period_s: float = 1.0,
        sample_period_s: float = 0.01,
        latency_s: float = 0.0,
        refit_worker: bool = False,
        config: LiveFitConfig | None = None,
        planner_mu_share: float = DEFAULT_PROBE_USE_FRACTION,
        decision_period_s: float | None = None,
        **config_overrides,
    ) -> None:
        """
        Args:
            params: the vehicle (model, bounds, nominal theta / prior).
            period_s: refit period [s].
            sample_period_s: data sampling period [s].
            latency_s: declared latency of a refit [s]: a refit started at t (on the data up
                to t) is published at the first sample update at or after t + latency_s, in
                simulated time (0: at once, in the event that starts it).
            refit_worker: run each refit in a worker thread on a copy of the estimator taken
                at its start, and publish it at the first sample update after both its
                declared latency has passed and the worker is done (for a loop paced to the
                wall clock, the LCM station: a refit then never holds up the controller's
                updates; the publication time depends on the computer, so a simulation keeps
                the default, in-event refits).
            config: fitting settings (default ``LiveFitConfig()``); ``sample_period_s`` replaces
                its data rate.
            planner_mu_share: the share of the handed mu the planner uses (the NMPC's
                ``speed_margin^2``), which the handing's exploration judges its levels by.
            decision_period_s: the period at which ``theta_hat`` is read (the NMPC's period, its
                updates on the period's multiples); a whole multiple of ``sample_period_s``
                (None: every sample; see "Rates").
            config_overrides: individual ``LiveFitConfig`` fields (e.g. ``horizon_steps=10``,
                ``fit_stiffness=True``); None values are ignored.
        """
        super().__init__()
        for name, value in (("period_s", period_s), ("sample_period_s", sample_period_s)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(
                    f"ContextFitter: {name} must be a positive number of seconds, got {value!r}"
                )
        if not (isinstance(latency_s, int | float) and 0 <= latency_s < period_s):
            raise ValueError(
                f"ContextFitter: latency_s must be >= 0 and below period_s ({period_s!r} s), "
                f"got {latency_s!r}"
            )
        self._latency_s = float(latency_s)
        self._decision_period_s, self._per_decision = _decision_period(
            decision_period_s, float(sample_period_s)
        )
        # The worker and its job in flight live outside the Context: a thread's future cannot be
        # copied into Drake state. Only a loop paced to the wall clock uses them. The worker
        # thread is started by the loop's thread and may inherit its real-time policy
        # (hardware.control_priority, or a loop started under chrt): it sets itself back to
        # ordinary scheduling, so a refit never preempts the loop.
        self._worker = (
            ThreadPoolExecutor(max_workers=1, initializer=normal_scheduling)
            if refit_worker
            else None
        )
        self._job = None
        base = LiveFitConfig() if config is None else config
        fields = {k: v for k, v in config_overrides.items() if v is not None}
        unknown = sorted(set(fields) - set(LiveFitConfig.__dataclass_fields__))
        if unknown:
            raise ValueError(f"ContextFitter: unknown setting(s) {unknown}")
        self._config = replace(base, sample_period_s=float(sample_period_s), **fields)
        self._params = params
        self._planner_mu_share = float(planner_mu_share)
        self._period_s = float(period_s)
        self._sample_period_s = float(sample_period_s)
        estimator = ContextEstimator(params, self._config, planner_mu_share=planner_mu_share)

        self._inputs = _SampleInputs.declare(self)
        self._frame_labels_port = self._inputs.frame_labels
        self._estimator_index = self.DeclareAbstractState(AbstractValue.Make(estimator))
        # From the start what the handing gives with no sample yet (the unknown value): the
        # controller's first update reads this state before the first decision is made.
        self._theta_index = self.DeclareDiscreteState(BasicVector(estimator.theta_for()))
        schedule = np.array([-math.inf, self._period_s])
        self._schedule_index = self.DeclareDiscreteState(BasicVector(schedule))
        self._held_port = None
        if self._per_decision > 1:
            self._held_port = self.DeclareVectorInputPort("held_samples", self.held_capacity * _ROW)
        # Without held samples: at each sample, taking it. With them: half a sample period
        # after the last sample before each decision tick, when HeldSamples holds it (its
        # update at that tick is done), before the controller's update reads theta_hat.
        offset = 0.0 if self._held_port is None else (self._per_decision - 0.5) * sample_period_s
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self._decision_period_s, offset_sec=offset, update=self._on_decision
        )
        self._theta_port = self.DeclareStateOutputPort("theta_hat", self._theta_index)
        self._table_port = self.DeclareAbstractOutputPort(
            "estimate_table",
            lambda: AbstractValue.Make(EstimateTable()),
            self._calc_table,
            prerequisites_of_calc={
                self.abstract_state_ticket(self._estimator_index),
                self.time_ticket(),
            },
        )

    @property
    def config(self) -> LiveFitConfig:
        return self._config

    @property
    def planner_mu_share(self) -> float:
        """The share of the handed mu the planner uses (the handing's exploration)."""
        return self._planner_mu_share

    @property
    def period_s(self) -> float:
        """Refit period [s]."""
        return self._period_s

    @property
    def latency_s(self) -> float:
        """Declared latency of a refit [s]."""
        return self._latency_s

    @property
    def sample_period_s(self) -> float:
        """Sampling period [s]."""
        return self._sample_period_s

    @property
    def decision_period_s(self) -> float:
        """Period at which ``theta_hat`` is decided [s]."""
        return self._decision_period_s

    def estimator(self, context: Context) -> ContextEstimator:
        """The estimator held in ``context`` with the samples held since the last decision
        taken in (read only: change it through events). Without held samples the context's
        own; else a copy that took them (refits due there run in it, never in the worker)."""
        estimator = context.get_abstract_state(self._estimator_index).get_value()
        rows, _, next_refit = self._held(context)
        if not len(rows):
            return estimator
        estimator = deepcopy(estimator)
        for row in rows:
            next_refit = self._take(context, estimator, row, next_refit, live=False)
        return estimator

    def _set_theta(self, state: State, estimator: ContextEstimator) -> None:
        theta = estimator.theta_for()
        if theta.shape != (NTHETA,) or not np.all(np.isfinite(theta)):
            theta = estimator.unknown_theta()
        state.get_mutable_discrete_state(self._theta_index).SetFromVector(theta)

    @property
    def held_capacity(self) -> int:
        """Rows the ``held_samples`` input holds (a decision's samples and one more)."""
        return self._per_decision + 1

    def _held(self, context: Context) -> tuple[np.ndarray, float, float]:
        """The held samples the estimator has not taken (time order), the time of the last it
        took and of the next refit [s]."""
        schedule = context.get_discrete_state(self._schedule_index).get_value()
        last, next_refit = float(schedule[_LAST_TAKEN]), float(schedule[_NEXT_REFIT])
        if self._held_port is None:
            return np.zeros((0, _ROW)), last, next_refit
        if not self._held_port.HasValue(context):
            raise RuntimeError(
                "ContextFitter: decision_period_s is longer than sample_period_s but the "
                "held_samples input is not connected (a HeldSamples system at the sample rate)"
            )
        rows = np.asarray(self._held_port.Eval(context)).reshape(self.held_capacity, _ROW)
        if math.isfinite(last) and rows[0, 0] > last + _TIME_EPS_S:
            raise RuntimeError(
                f"ContextFitter: samples lost at t={context.get_time():.6g} s: the oldest held "
                f"sample ({rows[0, 0]:.6g} s) is newer than the last one taken ({last:.6g} s)"
            )
        return rows[rows[:, 0] > last + _TIME_EPS_S], last, next_refit

    def _take(
        self, context: Context, estimator: ContextEstimator, row, next_refit: float, live: bool
    ) -> float:
        """The estimator's steps for one sample ``row`` (the refits due before it, the sample,
        a relabelling, publication, a refit due at its time), as a decision at every sample
        takes them; the next refit time. ``live`` False: no worker (a read of the state)."""
        t = float(row[0])
        while next_refit < t - _TIME_EPS_S:
            self._refit_at(context, estimator, next_refit, live)
            next_refit += self._period_s
        estimator.add_sample(t, row[1 : 1 + NX], row[1 + NX : 1 + NX + NU], row[1 + NX + NU])
        if self._relabel(context, estimator, float(row[-1])):
            self._start(estimator, t, live)  # a new terrain's first fit without waiting
        self._finish(estimator, t, live)
        if abs(t - next_refit) <= _TIME_EPS_S:
            self._refit_at(context, estimator, t, live)
            next_refit += self._period_s
        return next_refit

    def _refit_at(self, context: Context, estimator: ContextEstimator, t: float, live: bool):
        self._relabel(context, estimator)
        self._start(estimator, t, live)
        self._finish(estimator, t, live)

    def _on_decision(self, context: Context, state: State) -> EventStatus:
        """Take the samples since the last decision into the estimator (the held ones, or
        without held samples this one); decide ``theta_hat``."""
        estimator = state.get_mutable_abstract_state(self._estimator_index).get_mutable_value()
        rows, last, next_refit = self._held(context)
        if self._held_port is None:
            rows = self._inputs.row(context, self._config.relabel)[None, :]
        for row in rows:
            next_refit = self._take(context, estimator, row, next_refit, live=True)
        if len(rows):
            last = max(last, float(rows[-1, 0]))
        self._set_theta(state, estimator)
        schedule = np.array([last, next_refit])
        state.get_mutable_discrete_state(self._schedule_index).SetFromVector(schedule)
        return EventStatus.Succeeded()

    def _start(self, estimator: ContextEstimator, t: float, live: bool = True) -> None:
        """Start a refit at ``t`` (with a worker: on a copy, in the worker thread; not when
        ``live`` is False, a read of the state, which refits in the event)."""
        if not estimator.start_refit(t) or self._worker is None or not live:
            return
        copy = deepcopy(estimator)
        due = t + self._latency_s
        self._job = (copy, self._worker.submit(copy.finish_refit, due, self._latency_s))

    def _finish(self, estimator: ContextEstimator, t: float, live: bool = True) -> None:
        """Publish the refit in flight if it is due (and, with a worker, done)."""
        if self._worker is None or not live:
            estimator.finish_refit(t, self._latency_s)
            return
        if self._job is None or t < estimator.refit_started_s + self._latency_s - 1e-9:
            return
        copy, future = self._job
        if not future.done():
            return  # still running: the loop goes on with the last published estimate
        self._job = None
        try:
            done = future.result()
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            done = None
        if done is None:  # failed: the contexts stay pending and the next refit retries
            estimator.refit_started_s = math.nan
            return
        estimator.adopt(copy, done, t)

    def _relabel(
        self, context: Context, estimator: ContextEstimator, version: float | None = None
    ) -> bool:
        """Relabel the stored samples if ``frame_labels`` has a new version (``version``: the
        one a held sample saw; the labels are those standing now, which differ from its own
        only on frames after it unless a second re-clustering came in between); True if it
        had."""
        if version is not None and version <= estimator.labels_version:
            return False  # the sample saw no new version: no port read on the per-sample path
        if not (self._config.relabel and self._frame_labels_port.HasValue(context)):
            return False
        frames = self._frame_labels_port.Eval(context)
        seen = frames.version if version is None else version
        if seen <= estimator.labels_version:
            return False
        estimator.relabel(frames.t_s, frames.labels, frames.frame_period_s, version=frames.version)
        return True

    def _calc_table(self, context: Context, output: AbstractValue) -> None:
        own = context.get_abstract_state(self._estimator_index).get_value()
        output.set_value(own.table(context.get_time()))


class HeldSamples(LeafSystem):
    """Holds a :class:`ContextFitter`'s samples between its decisions.

    .. pydrake_system::

        name: HeldSamples
        input_ports:
        - state
        - actuation
        - context_id
        - frame_labels (optional)
        output_ports:
        - held_samples

    The inputs are the fitter's (connect the same sources). A periodic unrestricted update every
    ``sample_period_s`` (offset 0) appends the sample (time, state, actuation, context id,
    frame-labels version) to a ring of ``capacity`` rows, oldest first: ``held_samples``
    (``capacity`` x 12, from state). It is a system of its own because Drake copies the whole
    state of a system at each of its unrestricted updates: here a few numbers per sample, where
    the fitter's holds the estimator. Unrestricted, not discrete, so that a sample at the time of
    another system's update reads the inputs from before that update, as the fitter's own
    decision does.
    """

    def __init__(self, *, sample_period_s: float, capacity: int, relabel: bool = True) -> None:
        super().__init__()
        if not (isinstance(capacity, int) and capacity >= 1):
            raise ValueError(f"HeldSamples: capacity must be an int >= 1, got {capacity!r}")
        self._capacity = capacity
        self._relabel = bool(relabel)
        self._inputs = _SampleInputs.declare(self)
        rows = np.zeros((capacity, _ROW))
        rows[:, 0] = -math.inf  # empty
        self._rows_index = self.DeclareDiscreteState(BasicVector(rows.ravel()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=float(sample_period_s), offset_sec=0.0, update=self._on_sample
        )
        self.DeclareStateOutputPort("held_samples", self._rows_index)

    def _on_sample(self, context: Context, state: State) -> EventStatus:
        rows = context.get_discrete_state(self._rows_index).get_value()
        new = np.empty_like(rows)
        new[:-_ROW] = rows[_ROW:]
        new[-_ROW:] = self._inputs.row(context, self._relabel)
        state.get_mutable_discrete_state(self._rows_index).SetFromVector(new)
        return EventStatus.Succeeded()
