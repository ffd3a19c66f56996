"""The one component that decides what the controller gets (no pydrake).

The fitter says what the data say: per context a ``ContextEstimate`` (estimate, std,
identifiable or not). :class:`Handing` decides, with the rules stated once:

* per context a state (unknown, exploring, identified, backed off) and its handed theta
  (``pcvfe_drake.handing.context_state``);
* for the current frame a visit (``pcvfe_drake.handing.visit_tracker``): less friction is
  taken at once (a noise frame hands the unknown value where that is lower), more friction
  waits for confirmation;
* the unknown value (``pcvfe_drake.handing.unknown``) and exploration
  (``pcvfe_drake.estimation.probe``) judged relative to the level tried.

The estimator calls :meth:`Handing.observe` for every sample, :meth:`Handing.update` once per
refit with the estimates and its sample store (public ``labels``, ``times``, ``rows``), and
:meth:`Handing.theta` for what the controller gets.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.estimation.effect_fit import friction_used
from pcvfe_drake.estimation.probe import (
    DEFAULT_PROBE_USE_FRACTION,
    ProbeSettings,
    ProbeState,
    carried_probe,
    probe_update,
    unknown_probe_update,
)
from pcvfe_drake.estimation.sample_store import visit_members
from pcvfe_drake.handing.config import HandingConfig, Probe
from pcvfe_drake.handing.context_state import (
    ContextHanding,
    ModelError,
    context_state,
    handed_theta,
)
from pcvfe_drake.handing.unknown import unknown_theta, with_friction
from pcvfe_drake.handing.visit_tracker import VisitTracker
from pcvfe_drake.shallow_copy import shallow_copy

CARRY_SHARE = 0.8
"""The unknown phase's level is carried into a context only when this share of the level's
samples now belong to it (``probe.carried_probe``)."""


def _lower(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whichever theta has less friction."""
    return b if b[0] < a[0] else a


@dataclass
class Handing:
    """What the controller gets (see the module docstring).

    Args:
        config: the settings.
        prior_theta: the prior [mu, C_Sf, C_Sr] (the most friction any terrain is believed to
            have; the probe never hands more).
        vehicle: the ``VehicleParams`` (the probe's slip and force evidence).
        planner_mu_share: the share of the handed mu the planner uses (``speed_margin^2``),
            passed in when the diagram is built.
        identifiable_std: the fitter's std of an identifiable mu (a fit this tight but not
            identifiable is a level the probe rises to).
        model_error: the effect model's error and where it was calibrated.
        stiffness_law: how the tyre's small-slip stiffness follows the friction in the car's
            model (``EffectModel.stiffness_law``): the stiffness of a level handed before a
            context has a fit (:func:`~pcvfe_drake.handing.unknown.with_friction`).
    """

    config: HandingConfig
    prior_theta: tuple[float, float, float]
    vehicle: object
    planner_mu_share: float = DEFAULT_PROBE_USE_FRACTION
    identifiable_std: float = 0.05
    model_error: ModelError = field(default_factory=ModelError)
    stiffness_law: float = 0.0
    visit: VisitTracker = field(init=False)
    contexts: dict[int, ContextHanding] = field(default_factory=dict, init=False)
    unknown_probe: ProbeState = field(default_factory=ProbeState, init=False)
    """The unknown phase's probe (a stated floor; not started outside the phase)."""
    carried: ProbeState = field(default_factory=ProbeState, init=False)
    """The unknown probe at the end of the last phase, for the context that ended it."""
    last_fitted: int = field(default=-1, init=False)
    """The last context seen while it had a fit (``!LastKnown``)."""

    def __post_init__(self) -> None:
        cfg = self.config
        self.prior_theta = tuple(float(v) for v in self.prior_theta)
        self.visit = VisitTracker(cfg.noise_hold_s, cfg.confirm_rise_s)
        probe = cfg.unidentified if isinstance(cfg.unidentified, Probe) else Probe()
        self.probe_settings = ProbeSettings(
            use_fraction=self.planner_mu_share,
            floor_mu=cfg.floor_mu,
            max_excess=probe.max_excess,
            fast_step_rel=probe.fast_step_rel,
            hold_s=probe.hold_s,
            start_evidence=cfg.floor_stated,
        )

    def __deepcopy__(self, memo) -> Handing:
        other = shallow_copy(self)
        other.visit = shallow_copy(self.visit)
        other.contexts = {k: shallow_copy(v) for k, v in self.contexts.items()}
        return other

    def _context(self, ident: int) -> ContextHanding:
        return self.contexts.setdefault(ident, ContextHanding())

    # --- what the controller gets -------------------------------------------------------------

    def observe(self, t_s: float, ident: int, fitted: bool = False) -> None:
        """One sample's context id (-1 noise) at ``t_s``; ``fitted``: that context has a fit."""
        self.visit.observe(t_s, ident)
        if ident >= 0 and fitted:
            self.last_fitted = ident

    def theta(self, fits: Mapping) -> np.ndarray:
        """The theta for the current frame (``fits``: context id -> ``ContextEstimate``).

        The visited context's theta; on a noise frame at most the unknown value (less friction
        at once); while a switch to it waits for confirmation at most the confirmed one's."""
        ident = self.visit.visit()
        if ident < 0:
            return self.unknown(fits)
        theta = self._fitted_or_unknown(ident, fits)
        if self.visit.pending(ident):
            theta = _lower(theta, self._fitted_or_unknown(self.visit.confirmed, fits))
        if self.visit.in_noise:
            theta = _lower(theta, self.unknown(fits))
        return theta

    def context_theta(self, estimate) -> np.ndarray:
        """The theta a fitted context (``estimate``) is handed. The context that ends an unknown
        phase hands the phase's level until its own probe starts (at the next update: no dip
        back to the floor meanwhile)."""
        theta = np.array(estimate.theta, dtype=float)
        state = self.contexts.get(estimate.context_id, ContextHanding())
        probe = state.probe
        level = self.carried if self.carried.started else self.unknown_probe
        if not probe.started and level.started and estimate.context_id == self.visit.current:
            probe = level
        cfg = self.config
        theta = handed_theta(
            estimate, probe, theta, cfg.unidentified, cfg.floor_mu, self.model_error
        )
        return theta if np.all(np.isfinite(theta)) else np.array(self.prior_theta)

    def _fitted_or_unknown(self, ident: int, fits: Mapping) -> np.ndarray:
        estimate = fits.get(ident)
        if estimate is None or not estimate.fitted:
            return self.unfitted_theta(ident, fits)
        return self.context_theta(estimate)

    def probes_before_fit(self) -> bool:
        """Whether a confirmed context is explored before its first fit: with ``!Probe`` and a
        stated floor, where the data a context has before its fit were driven at the floor (or
        at the level carried into it), so they are a level tried, and the probe's evidence
        (bend ratios, slip angles, the friction used) reads the tyres without a fit."""
        return self.config.probing and self.config.floor_stated

    def unfitted_theta(self, ident: int, fits: Mapping) -> np.ndarray:
        """The theta of context ``ident`` while it has no fit: its probe's level where it is
        explored before its fit (:meth:`probes_before_fit`), with the stiffness the car's model
        states for that level, as the unknown value has it; else the unknown value."""
        state = self.contexts.get(ident)
        if state is None or not state.probe.started or not self.probes_before_fit():
            return self.unknown(fits)
        return with_friction(self.prior_theta, state.probe.mu, self.stiffness_law)

    def unknown(self, fits: Mapping) -> np.ndarray:
        """The theta while the terrain is unknown (``HandingConfig.unknown``), raised to the
        unknown phase's probe level where that is higher."""
        fitted = [e for e in fits.values() if e.fitted]
        last = fits.get(self.last_fitted)
        theta = unknown_theta(
            self.config.unknown,
            self.prior_theta,
            self.config.floor_mu,
            fitted=[
                (e.mu, e.mu_std, e.mu_lower_bound if e.mu_is_peak else math.nan) for e in fitted
            ],
            identified_mu=[float(self.context_theta(e)[0]) for e in fitted if e.identifiable],
            last_known_theta=None if last is None else last.theta,
            stiffness_law=self.stiffness_law,
        )
        if self.unknown_probe.started and self.unknown_probe.mu > theta[0]:
            theta = with_friction(theta, self.unknown_probe.mu, self.stiffness_law)
        return theta if np.all(np.isfinite(theta)) else np.array(self.prior_theta)

    def state(self, estimate) -> str:
        """The handing state of the context with the fitter's ``estimate``."""
        return context_state(
            estimate, self.contexts.get(estimate.context_id, ContextHanding()).probe
        )

    def probe_of(self, ident: int) -> ProbeState | None:
        """The context's probe (None: not probing)."""
        if not self.config.probing:
            return None
        return self.contexts.get(ident, ContextHanding()).probe

    # --- exploration --------------------------------------------------------------------------

    def renamed(self, old: int, new: int) -> None:
        """The re-clustering gave context ``old``'s data the id ``new``: ``new`` takes ``old``'s
        handing state (its probe's level, ceiling and steps; an identified spell), unless it
        has explored on its own."""
        mine, theirs = self.contexts.get(old), self.contexts.get(new)
        if mine is None or (theirs is not None and theirs.probe.started):
            return
        self.contexts[new] = copy.copy(mine)
        if self.last_fitted == old:
            self.last_fitted = new

    def adopt_exploration(self, other: Handing) -> None:
        """Take the exploration state (the probes, the unknown phase's probe and what it
        carries) of ``other``, a copy that ran a refit off the control path; the visit tracker
        stays this one's, which kept seeing frames meanwhile."""
        for ident, theirs in other.contexts.items():
            self._context(ident).probe = theirs.probe
        self.unknown_probe, self.carried = other.unknown_probe, other.carried

    def update(self, t_now: float, fits: Mapping, store) -> None:
        """One step of the probes at ``t_now`` (``!Probe``): a fitted, not identifiable current
        context (with a stated floor also a confirmed one before its first fit:
        :meth:`probes_before_fit`) raises, holds or backs off its level after checking its
        newest samples for large slip angles and the current level's data for the tyres' bend
        ratio; with a stated floor the unknown phase's level is probed too and carried into the
        context that ends the phase where it was tried on it. ``store``: the estimator's
        sample store."""
        if not self.config.probing:
            return
        phase = self.config.floor_stated and self._update_unknown_probe(t_now, store)
        ident = self.visit.current
        estimate = fits.get(ident)
        carried, self.carried = self.carried, ProbeState()
        if phase:  # a fitted context not confirmed yet starts from the phase's level as it is
            carried = self.unknown_probe
        fitted = estimate is not None and estimate.fitted
        if not fitted and not (self._confirmed(ident) and self.probes_before_fit()):
            return
        state = self._context(ident)
        if fitted and estimate.identifiable:  # handed until the next update: note its level
            mu = float(self.context_theta(estimate)[0])
            state.handed_fit_mu = (
                mu if math.isnan(state.handed_fit_mu) else max(state.handed_fit_mu, mu)
            )
            state.handed_fit_end_s = math.nan
            return
        labels, times = store.labels(), store.times()
        mine = visit_members(labels, times, ident, self.config.noise_hold_s)
        if not state.probe.started and carried.started:
            after = labels[times >= carried.last_step_s]
            state.probe = carried_probe(carried, after, ident) or state.probe

        def since(t0: float):  # the context's samples from t0 on: (times, states)
            t, states, _ = store.rows(np.flatnonzero(mine & (times >= t0)))
            return t, states

        if not fitted:  # before its first fit (probes_before_fit): the same rules and evidence,
            # the friction its data used as the demonstrated bound, the unknown value's
            # small-slip stiffness at the level as what the car drove with, no fit's interval
            t_all, s_all = since(-math.inf)
            used = friction_used(t_all, s_all, lateral_only=True) if t_all.size else math.nan
            state.probe = probe_update(
                state.probe,
                t_now,
                self.probe_settings,
                self.vehicle,
                used,
                self.unfitted_theta(ident, fits),
                since,
                self.prior_theta[0],
                stiffness_law=self.stiffness_law,  # the model's stiffness at the level
            )
            return
        hold_s = self.probe_settings.hold_s
        drove = math.nan  # an identified fit handed: for a hold after it the car's speed and
        if math.isfinite(state.handed_fit_mu):  # slips answer the fit's level, not the probe's
            if math.isnan(state.handed_fit_end_s):  # its first update not handed: it ended
                state.handed_fit_end_s = t_now
            if t_now - state.handed_fit_end_s < hold_s:
                drove = state.handed_fit_mu
            else:
                state.handed_fit_mu = state.handed_fit_end_s = math.nan
        handed = self.context_theta(estimate)  # what the car drove with
        tight = math.isfinite(estimate.mu_std) and estimate.mu_std <= self.identifiable_std
        shown = not (estimate.below_used or estimate.untrusted)  # a fit its data contradict
        target = estimate.mu if tight and shown else math.nan  # is no level to rise to
        state.probe = probe_update(
            state.probe,
            t_now,
            self.probe_settings,
            self.vehicle,
            estimate.mu_lower_bound,
            handed,
            since,
            self.prior_theta[0],
            drove_mu=drove,
            fit_mu=target,
        )

    def _confirmed(self, ident: int) -> bool:
        """``ident`` is a context whose visit is confirmed (reported for ``confirm_rise_s``)."""
        return ident >= 0 and not self.visit.pending(ident)

    def _update_unknown_probe(self, t_now: float, store) -> bool:
        """One step of the unknown phase's probe while the controller gets the unknown value
        (no context visited, or a switch not confirmed yet; a confirmed context without a fit
        ends the phase too where it is explored before its fit: :meth:`probes_before_fit`);
        at the phase's end it is kept in ``carried`` for the context that ended it. Returns
        whether the phase goes on."""
        ident = self.visit.visit()
        if self._confirmed(ident):  # fitted or not: with a stated floor it is explored
            if self.unknown_probe.started:
                self.carried, self.unknown_probe = self.unknown_probe, ProbeState()
            return False
        times = store.times()

        def since(t0: float):  # every sample from t0 on, whatever its label
            t, states, _ = store.rows(np.flatnonzero(times >= t0))
            return t, states

        prior = np.array(self.prior_theta)
        level = self.unknown_probe.mu if self.unknown_probe.started else self.config.floor_mu
        law = (level / prior[0]) ** self.stiffness_law  # 1 where the stiffness is kept
        t_level, s_level = since(self.unknown_probe.last_step_s)
        used = friction_used(t_level, s_level, lateral_only=True) if t_level.size else math.nan
        self.unknown_probe = unknown_probe_update(
            self.unknown_probe,
            t_now,
            self.probe_settings,
            self.vehicle,
            used,
            prior[0] * prior[1:] * law,  # the unknown value's small-slip stiffness
            since,
            prior[0],
            stiffness_law=self.stiffness_law,
        )
        return True
