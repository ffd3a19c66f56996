"""ContextFitter: context-specific friction estimation through the dynamics (paper IV-B)."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from copy import deepcopy
from dataclasses import replace

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, Context, EventStatus, LeafSystem, State

from pcvfe_drake.contexts.cluster_table import FrameLabels
from pcvfe_drake.estimation.context_estimator import ContextEstimator, EstimateTable
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.probe import DEFAULT_PROBE_USE_FRACTION
from pcvfe_drake.hardware.scheduling import normal_scheduling
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import NTHETA, NU, NX


class ContextFitter(LeafSystem):
    """Estimates theta = [mu, C_Sf, C_Sr] per terrain context and outputs the current one.

    .. pydrake_system::

        name: ContextFitter
        input_ports:
        - state
        - actuation
        - context_id
        - frame_labels (optional)
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

    Rates: a periodic unrestricted update every ``sample_period_s`` (default 0.01 s = 100 Hz)
    appends (t, state, actuation) with the current context id to the sample store and sets
    ``theta_hat`` (and relabels and refits when ``frame_labels`` has a new version); a periodic
    unrestricted update every ``period_s`` (default 1 s = 1 Hz, first at t = ``period_s``)
    starts a refit of the contexts whose data changed, on the data up to then, published
    ``latency_s`` later (the declared latency, in simulated time: the NMPC never waits for a
    refit, and a seed still gives one result; 0: published at once), bounded per update (see
    :class:`pcvfe_drake.estimation.live_fit_config.LiveFitConfig`: ``max_contexts_per_update``,
    ``max_windows``, ``max_iterations``). When both fire at once the sample is taken first. The
    :class:`ContextEstimator` (sample store, estimates) lives in the context's abstract state.
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

        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._actuation_port = self.DeclareVectorInputPort("actuation", NU)
        self._context_id_port = self.DeclareVectorInputPort("context_id", 1)
        self._frame_labels_port = self.DeclareAbstractInputPort(
            "frame_labels", AbstractValue.Make(FrameLabels())
        )
        self._estimator_index = self.DeclareAbstractState(AbstractValue.Make(estimator))
        self._theta_index = self.DeclareDiscreteState(BasicVector(estimator.prior_theta))
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self._sample_period_s, offset_sec=0.0, update=self._on_sample
        )
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self._period_s, offset_sec=self._period_s, update=self._on_refit
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

    def estimator(self, context: Context) -> ContextEstimator:
        """The estimator held in ``context`` (read only: change it through events)."""
        return context.get_abstract_state(self._estimator_index).get_value()

    def _set_theta(self, state: State, estimator: ContextEstimator) -> None:
        theta = estimator.theta_for()
        if theta.shape != (NTHETA,) or not np.all(np.isfinite(theta)):
            theta = estimator.prior_theta
        state.get_mutable_discrete_state(self._theta_index).SetFromVector(theta)

    def _on_sample(self, context: Context, state: State) -> EventStatus:
        estimator = state.get_mutable_abstract_state(self._estimator_index).get_mutable_value()
        estimator.add_sample(
            context.get_time(),
            self._state_port.Eval(context),
            self._actuation_port.Eval(context),
            self._context_id_port.Eval(context),
        )
        t = context.get_time()
        if self._relabel(context, estimator):
            self._start(estimator, t)  # a new terrain's first fit without waiting for the period
        self._finish(estimator, t)
        self._set_theta(state, estimator)
        return EventStatus.Succeeded()

    def _start(self, estimator: ContextEstimator, t: float) -> None:
        """Start a refit at ``t`` (with a worker: on a copy, in the worker thread)."""
        if not estimator.start_refit(t) or self._worker is None:
            return
        copy = deepcopy(estimator)
        due = t + self._latency_s
        self._job = (copy, self._worker.submit(copy.finish_refit, due, self._latency_s))

    def _finish(self, estimator: ContextEstimator, t: float) -> None:
        """Publish the refit in flight if it is due (and, with a worker, done)."""
        if self._worker is None:
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

    def _relabel(self, context: Context, estimator: ContextEstimator) -> bool:
        """Relabel the stored samples if ``frame_labels`` has a new version; True if it had."""
        if not (self._config.relabel and self._frame_labels_port.HasValue(context)):
            return False
        frames = self._frame_labels_port.Eval(context)
        if frames.version <= estimator.labels_version:
            return False
        estimator.relabel(frames.t_s, frames.labels, frames.frame_period_s, version=frames.version)
        return True

    def _on_refit(self, context: Context, state: State) -> EventStatus:
        estimator = state.get_mutable_abstract_state(self._estimator_index).get_mutable_value()
        self._relabel(context, estimator)
        self._start(estimator, context.get_time())
        self._finish(estimator, context.get_time())
        self._set_theta(state, estimator)
        return EventStatus.Succeeded()

    def _calc_table(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self.estimator(context).table(context.get_time()))
