"""The probes' updates of a ``ContextEstimator`` (no pydrake): the current context's probe
(``probe.probe_update``) and, with ``probe_unknown``, the unknown phase's
(``probe.unknown_probe_update``), carried into the context that ends the phase
(``probe.carried_probe``). The rules are in ``pcvfe_drake.estimation.probe``; this module
gathers each probe's samples from the estimator's store."""

from __future__ import annotations

import math

import numpy as np

from pcvfe_drake.estimation.effect_fit import friction_used
from pcvfe_drake.estimation.probe import (
    DEFAULT_PROBE_USE_FRACTION,
    ProbeState,
    carried_probe,
    probe_update,
    unknown_probe_update,
)


def update_probes(est, t_now: float) -> None:
    """One step of ``est``'s (a ``ContextEstimator``) probes at ``t_now``: a fitted, not
    identifiable current context raises, holds or backs off its handed mu after checking its
    newest ``probe_window_s`` for large slip angles and the current level's data for the tyres'
    bend ratio (``probe.level_bend``); with ``probe_unknown`` a context's probe starts from the
    unknown phase's level where that level was tried on it (the phase goes on while a switch to
    the context waits for its confirmation: the controller gets the lower of the two)."""
    cfg = est.config
    if cfg.unidentified_mu != "probe":
        return
    phase = cfg.probe_unknown and _update_unknown_probe(est, t_now)
    slot = est._slots.get(est.current_context)
    carried, est.carried = est.carried, ProbeState()
    if phase:  # a fitted context not confirmed yet starts from the phase's level as it is now
        carried = est.unknown_probe
    if slot is None or not slot.estimate.fitted:
        return
    if slot.estimate.identifiable:  # the fit is handed until the next update: note its level
        mu = float(est._unidentified(slot, np.array(slot.estimate.theta))[0])
        slot.handed_fit_mu = mu if math.isnan(slot.handed_fit_mu) else max(slot.handed_fit_mu, mu)
        slot.handed_fit_end_s = math.nan
        return
    labels, times = est._store.labels(), est._store.times()
    mine = labels == est.current_context
    if not slot.probe.started and carried.started:
        after = labels[times >= carried.last_step_s]
        slot.probe = carried_probe(carried, after, est.current_context) or slot.probe

    def since(t0: float):  # the context's samples from t0 on: (times, states)
        t, states, _ = est._store.rows(np.flatnonzero(mine & (times >= t0)))
        return t, states

    use = cfg.probe_use_fraction or DEFAULT_PROBE_USE_FRACTION
    drove = math.nan  # an identifiable fit handed: for probe_hold_s after it the car's speed
    if math.isfinite(slot.handed_fit_mu):  # and slips answer the fit's level, not the probe's
        if math.isnan(slot.handed_fit_end_s):  # its first update not handed: the spell ended
            slot.handed_fit_end_s = t_now
        if t_now - slot.handed_fit_end_s < cfg.probe_hold_s:
            drove = slot.handed_fit_mu
        else:
            slot.handed_fit_mu = slot.handed_fit_end_s = math.nan
    handed = est._unidentified(slot, np.array(slot.estimate.theta))  # what the car drove with
    fit = slot.estimate  # probe_fit_target: a tight fit, not identifiable, is the level's target
    tight = math.isfinite(fit.mu_std) and fit.mu_std <= cfg.identifiable_std
    target = fit.mu if cfg.probe_fit_target and tight and not fit.below_used else math.nan
    slot.probe = probe_update(
        slot.probe,
        t_now,
        cfg,
        est.params,
        slot.estimate.mu_lower_bound,
        handed,
        since,
        est._prior[0],
        use,
        drove_mu=drove,
        fit_mu=target,
    )


def _update_unknown_probe(est, t_now: float) -> bool:
    """One step of the unknown phase's probe while the controller gets the unknown-context
    value (no fitted context handed, or a switch to one not confirmed yet); at the phase's end
    it is kept in ``est.carried`` for the context that ended it. Returns whether the phase goes
    on."""
    ident = est.handed_context()
    slot = est._slots.get(ident)
    if slot is not None and slot.estimate.fitted and not est.switch.pending(ident):
        if est.unknown_probe.started:
            est.carried, est.unknown_probe = est.unknown_probe, ProbeState()
        return False
    times = est._store.times()

    def since(t0: float):  # every sample from t0 on, whatever its label
        t, states, _ = est._store.rows(np.flatnonzero(times >= t0))
        return t, states

    cfg, prior = est.config, np.array(est._prior)
    t_level, s_level = since(est.unknown_probe.last_step_s)
    used = friction_used(t_level, s_level, lateral_only=True) if t_level.size else math.nan
    est.unknown_probe = unknown_probe_update(
        est.unknown_probe,
        t_now,
        cfg,
        est.params,
        used,
        prior[0] * prior[1:],  # the unknown value keeps the prior's small-slip stiffness
        since,
        prior[0],
        cfg.probe_use_fraction or DEFAULT_PROBE_USE_FRACTION,
    )
    return True
