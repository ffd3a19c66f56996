"""Online per-context friction estimation: a labelled sample store, bounded refits, a table.

:class:`ContextEstimator` is the core of the ``ContextFitter`` LeafSystem (usable without Drake):
samples (time, state, input) are appended, labelled with the current context id, to one
time-ordered store (``sample_store.SampleStore``) at the data rate; :meth:`relabel` gives them
the labels of the clustering as it now stands (paper eq. 5d: after a re-clustering, the noise
samples of a terrain that was new join its context); :meth:`refit` refits contexts whose data
changed (samples gained, or relabelled in or out), a bounded amount of work per call (at most
``max_contexts_per_update`` contexts, round-robin, each on at most ``max_windows`` of its most
recent windows for at most ``max_iterations`` iterations, warm-started).

Rules (the "bad input" behaviour):

* samples with non-finite values are not stored (counted in ``rejected_samples``);
* noise/unknown samples (id < 0, or non-finite id) are stored with the label -1 and never
  fitted unless a relabelling gives them a context;
* a context with fewer than ``min_windows`` usable windows keeps the prior theta and its table
  entry says so (status ``"too_little_data"``);
* what the controller gets (current frame, noise frame, context without a fit) is decided by
  the handing (``pcvfe_drake.handing``: estimates in, handed theta and context states out);
* a refit whose solver diverges (non-finite loss or estimate) keeps the last good estimate and
  increments the context's ``diverged`` count;
* :meth:`ContextEstimator.theta_for` always returns finite numbers.

Drake copies the object at every state update; the chunked store's copy shares the full chunks
and copies the partly filled one. Memory: each label keeps its newest ``buffer_s`` of samples.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace

import numpy as np

from pcvfe_drake.blas_threads import one_blas_thread
from pcvfe_drake.estimation.effect_fit import EffectFitter, identifiability
from pcvfe_drake.estimation.estimate_latency import add_waits, newly_used, wait_quantiles
from pcvfe_drake.estimation.estimate_table import ContextEstimate, EstimateTable
from pcvfe_drake.estimation.fit_answer import distrust
from pcvfe_drake.estimation.fit_dataset import (
    build_windows,
)
from pcvfe_drake.estimation.fit_options import (
    STATUS_DIVERGED,
    FitOptions,
    FitResult,
    joint_options,
    without_model_error,
)
from pcvfe_drake.estimation.fit_quality import NoPeakSums, peak_check
from pcvfe_drake.estimation.fitting import fit_gauss_newton
from pcvfe_drake.estimation.incremental_fit import WindowInformation
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.probe import DEFAULT_PROBE_USE_FRACTION, wheel_peak_share
from pcvfe_drake.estimation.sample_store import (
    NOISE,
    SampleStore,
    labels_from_frames,
    ranges_mask,
    visit_members,
)
from pcvfe_drake.handing.handing import Handing
from pcvfe_drake.models.data import NoiseScaleCache
from pcvfe_drake.shallow_copy import shallow_copy
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import NU, NX


@dataclass
class _ContextSlot:
    """One context's estimate and counters (its samples are in the shared store)."""

    estimate: ContextEstimate
    samples: int = 0
    """Samples attributed to the context (received, plus relabelled in, minus relabelled out)."""
    changes: int = 0
    """Changes to its data (samples received or relabelled in or out), ever increasing."""
    changes_at_fit: int = 0
    estimate_data_end_s: float = math.nan
    """The newest sample time its published fit used [s] (NaN: none)."""
    delay_counts: np.ndarray | None = None
    """Histogram of its samples' waits from sample to published fit (``estimate_latency``)."""
    refit_delay_counts: np.ndarray | None = None
    """The same for the samples a later fit published (newer than its first fit's data)."""
    fit_info: WindowInformation | None = None
    """The effect fit's stored window information (``incremental_fit``; None: none yet, the
    next refit is a batch fit; after a relabelling it keeps the estimate and no window)."""
    noise_cache: NoiseScaleCache = field(default_factory=NoiseScaleCache)
    """Its buffer's noise scales, kept between refits (``models.data.NoiseScaleCache``)."""
    peak_sums: NoPeakSums | None = None
    """The tyre without a peak on its windows, kept for the next peak evidence
    (``fit_quality.peak_check``; forgotten with ``fit_info``'s windows)."""


def window_members(n: int, windows) -> np.ndarray:
    """(n,) mask of the samples that some window of a fit holds (``windows``: an effect fit's
    ``(data, starts, horizon, burn_in)``; a window spans samples ``start .. start + horizon``)."""
    _, starts, horizon, _ = windows
    starts = np.asarray(starts, dtype=np.int64)
    return ranges_mask(n, starts, starts + horizon)


def effect_fitter(params: VehicleParams, config: LiveFitConfig) -> EffectFitter:
    """The effect-model fitter a context estimator with ``config`` refits its contexts with
    (``config.effects``, its windows, iterations and model-error budget)."""
    return EffectFitter(
        params,
        config.effects,
        horizon_s=config.effect_horizon_s,
        stride_s=config.effect_stride_s,
        max_windows=config.effect_max_windows,
        max_iterations=config.max_iterations,
        min_windows=config.effect_min_windows,
        model_error_rel=config.model_error_rel,
    )


def _discarded(old: ContextEstimate, samples: int, t_now: float, what: str) -> ContextEstimate:
    """The table entry after a refit that was thrown away (``what`` happened at ``t_now``):
    the last good estimate (or the prior) stays, counted as diverged."""
    return replace(
        old,
        samples=samples,
        status="diverged",
        diverged=old.diverged + 1,
        message=f"refit at t={t_now:.3g} s {what}; keeping the last good "
        f"{'estimate' if old.fitted else 'prior'}",
    )


@dataclass
class ContextEstimator:
    """Per-context buffers and estimates (see the module docstring)."""

    params: VehicleParams
    config: LiveFitConfig = field(default_factory=LiveFitConfig)
    _slots: dict[int, _ContextSlot] = field(default_factory=dict)
    _next_rr: int = 0
    rejected_samples: int = 0
    noise_samples: int = 0
    last_sample_time_s: float = -math.inf
    last_fitted_context: int = -1
    labels_version: int = 0
    relabelled_samples: int = 0
    planner_mu_share: float = DEFAULT_PROBE_USE_FRACTION
    """The share of the handed mu the planner uses (``speed_margin^2``), for the handing."""
    refit_started_s: float = math.nan
    """Start [s] of the refit in flight (:meth:`start_refit`; its data end there), NaN: none."""
    refit_finished_s: float = math.nan
    """When the last refit was due to be published [s] (start + declared latency)."""
    late_refits: int = 0
    """Refits a worker published later than their declared latency (:meth:`adopt`)."""

    def __post_init__(self) -> None:
        prior = self.params.theta if self.config.prior_theta is None else self.config.prior_theta
        self._prior = tuple(float(v) for v in prior)
        self.handing = Handing(
            self.config.handing,
            self._prior,
            self.params,
            planner_mu_share=self.planner_mu_share,
            identifiable_std=self.config.identifiable_std,
            model_error=self.config.model_error(),
            stiffness_law=self.config.model.stiffness_law,
        )
        capacity = max(1, int(round(self.config.buffer_s / self.config.sample_period_s)))
        self._capacity = capacity
        self._store = SampleStore()
        if self.config.fit_stiffness:
            self._options = joint_options(
                self.params,
                rel_sigma=self.config.stiffness_prior_rel,
                max_iterations=self.config.max_iterations,
                min_windows=self.config.min_windows,
                model_error_rel=self.config.model_error_rel,
            )
        else:
            self._options = FitOptions(
                max_iterations=self.config.max_iterations,
                min_windows=self.config.min_windows,
                model_error_rel=self.config.model_error_rel,
            )
        self._effect_fitter = (
            effect_fitter(self.params, self.config) if self.config.effects else None
        )

    def __deepcopy__(self, memo) -> ContextEstimator:
        other = shallow_copy(self)
        other._slots = {k: shallow_copy(v) for k, v in self._slots.items()}
        other.handing = copy.deepcopy(self.handing, memo)
        other._store = copy.deepcopy(self._store, memo)
        return other

    @property
    def prior_theta(self) -> np.ndarray:
        return np.array(self._prior)

    @property
    def context_ids(self) -> list[int]:
        return sorted(self._slots)

    def add_sample(self, t: float, state, inputs, context_id) -> int:
        """Store one sample; returns the context id used (-1: noise/unknown or rejected)."""
        state = np.asarray(state, dtype=float).reshape(-1)
        inputs = np.asarray(inputs, dtype=float).reshape(-1)
        if state.shape != (NX,) or inputs.shape != (NU,):
            raise ValueError(
                f"add_sample: state must have {NX} and inputs {NU} entries, got "
                f"{state.shape} and {inputs.shape}"
            )
        cid = float(np.asarray(context_id, dtype=float).reshape(-1)[0])
        ident = int(round(cid)) if math.isfinite(cid) and cid >= 0 else -1
        slot = self._slots.get(ident)
        self.handing.observe(t, ident, slot is not None and slot.estimate.fitted)
        if math.isfinite(t):
            self.last_sample_time_s = t
        # the arrays' own ``all`` (not ``np.all``'s dispatch): the same test, cheaper per sample
        if not (math.isfinite(t) and np.isfinite(state).all() and np.isfinite(inputs).all()):
            self.rejected_samples += 1
            return -1
        self._store.append(t, state, inputs, ident)
        if len(self._store) > (len(self._slots) + 2) * self._capacity:
            self._store.retain(self._capacity)  # amortised: drops at least one buffer's worth
        if ident < 0:
            self.noise_samples += 1
            return -1
        slot = self._slot(ident)
        slot.samples += 1
        slot.changes += 1
        if slot.estimate.fitted:
            self.last_fitted_context = ident
        return ident

    def _slot(self, ident: int) -> _ContextSlot:
        slot = self._slots.get(ident)
        if slot is None:
            slot = _ContextSlot(ContextEstimate(ident, self._prior, (float("nan"),) * 3))
            self._slots[ident] = slot
        return slot

    def relabel(
        self,
        frame_t_s,
        frame_labels,
        frame_period_s: float,
        version: int | None = None,
    ) -> dict[int, int]:
        """Give the stored samples the labels of the clustering as it now stands (eq. 5d).

        Each sample takes the label of the clustering's frame that covers its time
        (:func:`pcvfe_drake.estimation.sample_store.labels_from_frames`): the noise samples of a
        terrain that was new when they were taken join its context once a re-clustering has
        found it. Contexts whose data changed are refitted by the next :meth:`refit` calls
        (round-robin, bounded as always).

        Args:
            frame_t_s: (M,) times of the clustering's stored frames [s].
            frame_labels: (M,) their current context ids (-1 noise).
            frame_period_s: the camera period [s].
            version: the clustering's label version (re-clusterings so far); a version already
                applied is skipped (None: relabel anyway).

        Returns:
            {context id: net samples gained (negative: lost)} for the contexts that changed
            (-1: noise).
        """
        if version is not None:
            if int(version) <= self.labels_version:
                return {}
            self.labels_version = int(version)
        old = self._store.labels()
        new = labels_from_frames(
            self._store.times(), old, frame_t_s, frame_labels, float(frame_period_s)
        )
        moved = new != old
        if not moved.any():
            return {}
        self._store.set_labels(new)
        self.relabelled_samples += int(moved.sum())
        gained: dict[int, int] = {}
        for label, sign in ((old[moved], -1), (new[moved], 1)):
            ids, counts = np.unique(label, return_counts=True)
            for ident, count in zip(ids.tolist(), counts.tolist(), strict=True):
                gained[ident] = gained.get(ident, 0) + sign * count
                if ident != NOISE:
                    slot = self._slot(ident)
                    slot.samples += sign * count
                    slot.changes += count
                    if slot.fit_info is not None:  # not an append: every window re-evaluated
                        slot.fit_info = slot.fit_info.forget_windows()
                    slot.peak_sums = None
        self._follow_renamings(old, new, moved)
        return {k: v for k, v in gained.items() if v}

    def _follow_renamings(self, old: np.ndarray, new: np.ndarray, moved: np.ndarray) -> None:
        """A context the re-clustering renamed passes its fit and its handing (also a probe
        started before its first fit) to the new id: no sample keeps the old id and most of
        them now carry one other id that has no fit of its own. These are the same data under
        another name, not a new terrain, so the new id is not explored from the floor again;
        its next refit starts from the fit it took over. ``moved``: the samples whose label
        changed (only their old ids can have been renamed)."""
        for ident in np.unique(old[moved & (old >= 0)]).tolist():
            of_old = old == ident
            if (new == ident).any():
                continue
            to, counts = np.unique(new[of_old], return_counts=True)
            heir = int(to[counts.argmax()])
            mine, theirs = self._slots.get(ident), self._slots.get(heir)
            if heir < 0 or 2 * int(counts.max()) <= int(of_old.sum()):
                continue
            probe = self.handing.probe_of(ident)
            explored = probe is not None and probe.started  # explored before its first fit
            if mine is None or not (mine.estimate.fitted or explored):
                continue
            if theirs is not None and theirs.estimate.fitted:
                continue  # a merge into a fitted context: its own fit and handing stand
            if mine.estimate.fitted:
                slot = self._slot(heir)
                slot.estimate = replace(mine.estimate, context_id=heir)
                # The samples its fit used were used: they do not wait again under the new id.
                slot.estimate_data_end_s = mine.estimate_data_end_s
                slot.delay_counts = mine.delay_counts
                slot.refit_delay_counts = mine.refit_delay_counts
            self.handing.renamed(ident, heir)

    @property
    def current_context(self) -> int:
        """The latest sample's context id (-1: noise)."""
        return self.handing.visit.current

    def fits(self) -> dict:
        """{context id: its ``ContextEstimate``}: what the fitter says, for the handing."""
        return {k: s.estimate for k, s in self._slots.items()}

    def handed_context(self) -> int:
        """The context being visited (``handing.visit_tracker``): the current one; while noise,
        the last known one within the noise hold; else -1 (unknown)."""
        return self.handing.visit.visit()

    def theta_for(self, context_id: int | None = None) -> np.ndarray:
        """theta in use for ``context_id`` (default: what the controller gets now): always
        finite. An explicit id gets its own theta (the prior until fitted); the current frame's
        is the handing's decision (``pcvfe_drake.handing.handing.Handing.theta``)."""
        if context_id is None:
            return self.handing.theta(self.fits())
        slot = self._slots.get(int(context_id))
        if slot is not None and not slot.estimate.fitted and self.handing.probes_before_fit():
            probe = self.handing.probe_of(int(context_id))
            if probe is not None and probe.started:  # explored before its first fit
                return self.handing.unfitted_theta(int(context_id), self.fits())
        if slot is None or not slot.estimate.fitted:
            theta = np.array(self._prior if slot is None else slot.estimate.theta)
            return theta if np.all(np.isfinite(theta)) else np.array(self._prior)
        return self.handing.context_theta(slot.estimate)

    def handing_state(self, context_id: int) -> str:
        """The context's handing state (unknown, exploring, identified, backed off)."""
        slot = self._slots.get(int(context_id))
        if slot is None:
            return "unknown"
        return self.handing.state(slot.estimate)

    def update_probe(self, t_now: float) -> None:
        """One step of the handing's exploration (``Handing.update``; called by
        :meth:`refit`)."""
        self.handing.update(t_now, self.fits(), self._store)

    def unknown_theta(self) -> np.ndarray:
        """theta the controller gets while the context is unknown (``HandingConfig.unknown``)."""
        return self.handing.unknown(self.fits())

    def pending(self) -> list[int]:
        """Contexts whose data changed since their last refit, in round-robin order."""
        ids = [k for k, s in sorted(self._slots.items()) if s.changes > s.changes_at_fit]
        later = [k for k in ids if k >= self._next_rr]
        return later + [k for k in ids if k < self._next_rr]

    def start_refit(self, t_now: float) -> bool:
        """Start a refit at ``t_now``: it will use the data up to ``t_now`` (False: one is in
        flight already, this start is dropped)."""
        if math.isfinite(self.refit_started_s):
            return False
        self.refit_started_s = float(t_now)
        return True

    def finish_refit(self, t_now: float, latency_s: float, fit=fit_gauss_newton):
        """Finish the refit in flight once its declared latency has passed (``t_now >=
        start + latency_s``): it runs on the data up to its start and is published at
        ``t_now``, so a simulation gives one result whatever the computer (the simulated
        time of publication comes from the declared latency, not from the wall clock).
        Returns the refitted ids, None when nothing was due."""
        start = self.refit_started_s
        if not math.isfinite(start) or t_now < start + latency_s - 1e-9:
            return None
        self.refit_started_s = math.nan
        self.refit_finished_s = float(t_now)
        return self.refit(t_now, fit, data_until_s=start)

    def adopt(self, worker: ContextEstimator, done: list[int], t_now: float) -> None:
        """Publish at ``t_now`` the refit that a worker ran on a copy of this estimator (taken
        when the refit started): the refitted contexts take its estimates, stored window
        information and wait statistics (their sample counts stay this estimator's, which
        kept receiving samples), and the handing its exploration state after it."""
        for ident in done:
            mine, theirs = self._slot(ident), worker._slots[ident]
            mine.estimate = replace(theirs.estimate, samples=mine.samples)
            mine.changes_at_fit = theirs.changes_at_fit
            mine.fit_info = theirs.fit_info
            mine.peak_sums = theirs.peak_sums
            mine.noise_cache = theirs.noise_cache
            mine.estimate_data_end_s = theirs.estimate_data_end_s
            mine.delay_counts = theirs.delay_counts
            mine.refit_delay_counts = theirs.refit_delay_counts
        self.handing.adopt_exploration(worker.handing)
        self._next_rr = worker._next_rr
        self.refit_started_s = math.nan
        if t_now > worker.refit_finished_s + self.config.sample_period_s:
            self.late_refits += 1

    def refit(self, t_now: float, fit=fit_gauss_newton, data_until_s: float | None = None):
        """Refit up to ``max_contexts_per_update`` pending contexts; returns their ids.

        ``fit`` is the solver (``fit_gauss_newton`` signature); replaceable for testing.
        ``data_until_s``: use only the samples up to this time (a refit started then and
        published at ``t_now``; default: all).
        """
        self.update_probe(t_now)
        done = []
        # One BLAS thread, as the clustering's re-clustering: the fits' products are small
        # (a refit's largest is a dot product of ~10^5 entries), and a threaded BLAS spends
        # several times their CPU in its threads' hand-overs, worse on a loaded machine; a
        # threaded dot product's sum also depends on how many threads the machine gives it.
        with one_blas_thread():
            for ident in self.pending()[: self.config.max_contexts_per_update]:
                self._refit_one(ident, t_now, fit, data_until_s)
                done.append(ident)
                self._next_rr = ident + 1
        return done

    def _refit_one(self, ident: int, t_now: float, fit, data_until_s=None) -> None:
        cfg = self.config
        slot = self._slots[ident]
        slot.changes_at_fit = slot.changes
        old = slot.estimate
        labels, times = self._store.labels(), self._store.times()
        if data_until_s is not None:  # the data up to then (the store is in time order)
            n = int(np.searchsorted(times, data_until_s + 1e-9, side="right"))
            labels, times = labels[:n], times[:n]
        mine = visit_members(labels, times, ident, cfg.handing.noise_hold_s)
        rows = np.flatnonzero(mine)[-self._capacity :]
        t, states, inputs = self._store.rows(rows)
        if self._effect_fitter is not None:
            self._refit_effects(slot, t, states, inputs, t_now)
            return
        split = build_windows(
            t,
            states,
            inputs,
            horizon=cfg.horizon_steps,
            stride=cfg.stride_steps,
            v_min=cfg.min_speed_mps,
            dt=cfg.sample_period_s,
            x0_smoothing_s=cfg.x0_smoothing_s,
            max_windows=None,  # the most recent max_windows are taken below
        )
        data = split.by_context.get(0)
        n_windows = 0 if data is None else data.n_windows
        samples = slot.samples
        if n_windows < cfg.min_windows:
            skipped = ", ".join(f"{k} {v}" for k, v in split.skipped.items() if v)
            slot.estimate = replace(
                old,
                samples=samples,
                status=old.status if old.fitted else "too_little_data",
                message=(
                    f"too little data: {n_windows} usable windows < {cfg.min_windows}"
                    + (f" (skipped: {skipped})" if skipped else "")
                    + ("; keeping the last estimate" if old.fitted else "; using the prior")
                ),
            )
            return
        if n_windows > cfg.max_windows:
            data = data.subset(slice(n_windows - cfg.max_windows, None))
        start = np.array(old.theta) if old.fitted else np.array(self._prior)
        try:
            result: FitResult = fit(data, self.params, start, self._options)
            ok = (
                result.status != STATUS_DIVERGED
                and np.all(np.isfinite(result.theta))
                and math.isfinite(result.loss)
            )
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            result, ok = None, False
            reason = f"{type(exc).__name__}: {exc}"
        if not ok:
            if result is not None:
                reason = "; ".join(result.warnings) or result.status
            slot.estimate = _discarded(old, samples, t_now, f"diverged ({reason})")
            return
        std = np.where(np.isfinite(result.std), result.std, np.nan)
        judged = self._identifiability(old, t, states, result.theta[0], std[0], False)
        untrusted = distrust(result.quality) or ""
        if untrusted:
            judged["identifiable"] = False
        slot.estimate = ContextEstimate(
            context_id=ident,
            theta=tuple(float(v) for v in result.theta),
            theta_std=tuple(float(v) for v in std),
            samples=samples,
            n_windows=data.n_windows,
            last_update_s=float(t_now),
            first_fit_s=old.first_fit_s if old.fitted else float(t_now),
            status="fitted" if result.converged else "fitting",
            fits=old.fits + 1,
            diverged=old.diverged,
            loss=float(result.loss),
            message="; ".join(result.warnings),
            untrusted=untrusted,
            **judged,
        )
        # the windows fitted (in time order, indices into t): the newest one's end is the
        # newest sample the fit used, and only samples some window holds reached it
        windows = (data, data.start, data.horizon, 0)
        end_s = float(t[int(data.start[-1]) + data.horizon])
        self._published(slot, t, end_s, t_now, window_members(t.size, windows))

    def _refit_effects(self, slot: _ContextSlot, t, states, inputs, t_now: float) -> None:
        """``fitter.effects``: refit the context with the workbench's effect model."""
        cfg = self.config
        old = slot.estimate
        samples = slot.samples
        previous = tuple(v for _, v, _ in old.model_params) if old.fitted else None
        try:
            if cfg.effect_incremental:
                result, slot.fit_info = self._effect_fitter.refit(
                    t, states, inputs, slot.fit_info, self._prior[0], previous, slot.noise_cache
                )
            else:
                result = self._effect_fitter(
                    t, states, inputs, previous, self._prior[0], noise_cache=slot.noise_cache
                )
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            slot.fit_info, slot.peak_sums = None, None
            slot.estimate = _discarded(old, samples, t_now, f"failed ({type(exc).__name__}: {exc})")
            return
        if result is None:
            slot.estimate = replace(
                old,
                samples=samples,
                status=old.status if old.fitted else "too_little_data",
                message=f"too little data for the effect model (< {cfg.effect_min_windows} "
                f"windows of {cfg.effect_horizon_s:g} s)"
                + ("; keeping the last estimate" if old.fitted else "; using the prior"),
            )
            return
        if not (np.all(np.isfinite(result.theta)) and math.isfinite(result.loss)):
            slot.fit_info, slot.peak_sums = None, None
            slot.estimate = _discarded(old, samples, t_now, "diverged")
            return
        peak = result.mu_is_peak
        track = dict(zip(result.param_names, result.model_theta, strict=True)).get(
            "track_slip.t", 0
        )
        share = math.nan  # with the track in the model, how near each wheel came to its peak
        if peak and track > 0:
            th = np.asarray(result.theta, dtype=float)
            share = wheel_peak_share(t, states, self.params, th[0], th[0] * th[1:], track)
        judged = self._identifiability(old, t, states, result.theta[0], result.std[0], peak, share)
        untrusted = ""  # a peak the data do not show is not identified (fit_quality)
        if peak and judged["identifiable"]:
            untrusted, slot.peak_sums = peak_check(self._effect_fitter, result, slot.peak_sums)
            judged["identifiable"] = not untrusted
        slot.estimate = ContextEstimate(
            context_id=old.context_id,
            theta=tuple(float(v) for v in result.theta),
            theta_std=tuple(float(v) for v in result.std),
            samples=samples,
            n_windows=result.n_windows,
            last_update_s=float(t_now),
            first_fit_s=old.first_fit_s if old.fitted else float(t_now),
            status="fitted" if result.converged else "fitting",
            fits=old.fits + 1,
            diverged=old.diverged,
            loss=result.loss,
            message="; ".join(result.warnings),
            mu_is_peak=result.mu_is_peak,
            model_params=tuple(
                (n, float(v), float(sd))
                for n, v, sd in zip(
                    result.param_names, result.model_theta, result.model_std, strict=True
                )
            ),
            untrusted=untrusted,
            **judged,
        )
        self._published(slot, t, result.data_end_s, t_now, window_members(t.size, result.windows))

    def _published(
        self,
        slot: _ContextSlot,
        t: np.ndarray,
        data_end_s: float,
        t_now: float,
        used: np.ndarray | None = None,
    ):
        """A fit using the samples up to ``data_end_s`` is published at ``t_now``: the samples
        newer than the previous fit's data waited ``t_now - t_sample``; the entry gets
        ``data_end_s`` and the waits' p50 and p99, over all samples and over those a refit
        published (after the context's first fit: what the refits' cadence costs, without the
        wait for the first fit's data). ``used``: which of ``t`` the fit's windows hold (None:
        all; :func:`estimate_latency.newly_used`)."""
        previous = slot.estimate_data_end_s
        refit = math.isfinite(previous)
        new = newly_used(t, previous, data_end_s, used)
        slot.delay_counts = add_waits(slot.delay_counts, t_now - new)
        if refit:
            slot.refit_delay_counts = add_waits(slot.refit_delay_counts, t_now - new)
        slot.estimate_data_end_s = float(data_end_s)
        slot.estimate = replace(
            slot.estimate,
            data_end_s=float(data_end_s),
            sample_to_estimate_s=wait_quantiles(slot.delay_counts),
            sample_to_refit_s=wait_quantiles(slot.refit_delay_counts),
        )

    def _identifiability(
        self, old: ContextEstimate, t, states, mu, std, peak: bool, share: float = math.nan
    ) -> dict:
        cfg = self.config
        lower = old.mu_lower_bound
        data_std = without_model_error(mu, std, cfg.model_error_rel)
        return identifiability(
            t,
            states,
            mu,
            data_std,
            peak,
            lower,
            cfg.near_limit_fraction,
            cfg.identifiable_std,
            share,
        )

    def table(self, time_s: float = float("nan")) -> EstimateTable:
        """The estimate table (sample counts as of now)."""
        entries = tuple(
            replace(
                slot.estimate,
                samples=slot.samples,
                probe=self.handing.probe_of(k),
                handing=self.handing.state(slot.estimate),
            )
            for k, slot in sorted(self._slots.items())
        )
        return EstimateTable(
            entries=entries,
            prior_theta=self._prior,
            time_s=float(time_s),
            rejected_samples=self.rejected_samples,
            noise_samples=self.noise_samples,
            relabelled_samples=self.relabelled_samples,
            labels_version=self.labels_version,
        )
