"""The workbench's loop: forward selection of library effects with a backward check.

Starting from the baseline (or the model the user gives with ``--add``):

1. *rank*: every library effect not in the model is added alone on top of it, fitted on the
   training blocks and scored on the held-out blocks; it is *significant* when

   - the likelihood-ratio test of the training fit passes at ``alpha`` / (number of effects
     ranked in this round) (Bonferroni),
   - the held-out model error falls by at least ``min_drop`` (the paired test of the
     held-out windows, ``drop_p_value``, is reported beside every drop; short logs have too
     few held-out windows for it to be a gate: a 45 s log gives p = 0.05 for a drag that
     removes the whole error with a likelihood-ratio p of 1e-30),
   - and none of its parameters sits at a bound (a parameter at a bound is flagged, its
     uncertainty is not defined and the effect is never called significant);

2. *add* the significant effect with the largest held-out error drop (equal drops: the larger
   likelihood-ratio statistic);
3. *backward check*: every earlier effect of the model is taken out again in turn; one whose
   removal the likelihood-ratio test does not reject (p >= ``alpha``) is removed (the newer
   effect explains what it did) and is not offered again;
4. repeat from 1 until no effect is significant (or ``max_steps``).

Every step records the held-out model error before and after, the p-values and the fitted
parameters; :func:`run_selection` returns them JSON-ready. The final model is then tested for
structure the library does not explain (:mod:`pcvfe_drake.workbench.verdict`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from pcvfe_drake.models.estimate import FitResult
from pcvfe_drake.workbench.evidence import error_drop, paired_drop_test


@dataclass
class Trial:
    """One effect added on top of a reference model."""

    name: str
    fit: FitResult
    evaluation: dict
    lr: float
    dof: int
    p_value: float
    drop: float
    drop_test: dict
    at_bound: list[str]
    significant: bool
    reference_eval: dict
    signature: dict = field(default_factory=dict)

    def note(self, reference_at_floor: bool, alpha: float) -> str:
        if self.at_bound:
            return f"parameter at a bound ({', '.join(self.at_bound)}): not significant"
        if reference_at_floor and self.drop_test["p_value"] >= alpha:
            return "the model before is already at the noise floor: no drop to measure"
        if self.drop_test["p_value"] >= alpha:
            if self.significant:
                return (
                    f"the held-out drop alone is not conclusive (p = "
                    f"{self.drop_test['p_value']:.2g}): few held-out windows"
                )
            return "the held-out error change is within the noise"
        return ""

    def summary(self, reference_at_floor: bool = False, alpha: float = 0.01) -> dict:
        ref = self.reference_eval
        ev = self.evaluation
        return {
            "name": self.name,
            "significant": bool(self.significant),
            "p_value": float(self.p_value),
            "confidence": float(1.0 - self.p_value),
            "lr_statistic": float(self.lr),
            "dof": int(self.dof),
            "heldout_error": float(ev["model_error"]),
            "heldout_error_before": float(ref["model_error"]),
            "heldout_error_drop": float(self.drop),
            "drop_p_value": float(self.drop_test["p_value"]),
            "drop_note": self.note(reference_at_floor, alpha),
            "heldout_multistep_error": float(ev["multistep_error"]),
            "heldout_multistep_error_before": float(ref["multistep_error"]),
            "heldout_multistep_error_drop": float(
                1.0 - ev["multistep_error"] / max(ref["multistep_error"], 1e-300)
            ),
            "noise_floor": float(ev["noise_floor"]),
            "params": self.fit.params_dict(only_effects=True, effect=self.name),
            "at_bound": list(self.at_bound),
            "signature": self.signature,
        }


def effect_at_bound(fit: FitResult, name: str) -> list[str]:
    """Parameters of effect ``name`` at a bound that is not the effect's null value."""
    lo, hi = fit.model.bounds()
    out = []
    for j in fit.model.effect_param_indices(name):
        p = fit.model.params[j]
        tol = 1e-6 * (hi[j] - lo[j])
        at = fit.theta[j] <= lo[j] + tol or fit.theta[j] >= hi[j] - tol
        if at and abs(fit.theta[j] - p.null) > tol:
            out.append(p.name)
    return out


def lr_test(small: FitResult, big: FitResult) -> tuple[float, int, float]:
    """Likelihood-ratio statistic, degrees of freedom and p-value of ``big`` over ``small``
    (nested; one observation per training window and fitted state)."""
    dof = big.model.n_params - small.model.n_params
    lr = max(0.0, small.n_eff * float(np.log(small.cost / max(big.cost, 1e-300))))
    return lr, dof, float(chi2.sf(lr, dof)) if dof > 0 else 1.0


def try_effect(wb, ref: FitResult, ref_eval: dict, name: str, n_tests: int) -> Trial:
    """Fit ``ref``'s model plus effect ``name`` and test it against ``ref``."""
    cfg = wb.config
    alt = wb.fit_model(ref.model.with_effects(name), warm=ref)
    lr, dof, p = lr_test(ref, alt)
    ev = wb.evaluate(alt, with_free_run=False)
    drop = error_drop(ref_eval, ev)
    dtest = paired_drop_test(ref_eval, ev, wb.window_group)
    bound = effect_at_bound(alt, name)
    sig = p < cfg.alpha / max(n_tests, 1) and drop >= cfg.min_drop and not bound
    return Trial(name, alt, ev, lr, dof, p, drop, dtest, bound, bool(sig), ref_eval)


def run_selection(wb, candidates: list[str], start: list[str], max_steps: int = 8) -> dict:
    """Forward selection with a backward check (module docstring); JSON-ready plus the final
    fit and its evaluation under the keys ``_final`` and ``_final_eval``."""
    cfg = wb.config
    if start:
        cur = wb.fit_model(wb.base_model.with_effects(*start), warm=wb.baseline)
        cur_eval = wb.evaluate(cur, with_free_run=False)
    else:
        cur, cur_eval = wb.baseline, wb.baseline_eval
    sigs = wb.signatures(candidates)
    removed: set[str] = set()
    rounds: list[dict] = []
    path: list[dict] = []
    first: list[Trial] = []
    last: list[Trial] = []
    for _ in range(max_steps):
        pool = [c for c in candidates if c not in cur.model.effect_names and c not in removed]
        if not pool:
            last = []
            break
        at_floor = wb.at_floor(cur_eval)
        trials = [try_effect(wb, cur, cur_eval, name, len(pool)) for name in pool]
        for t in trials:
            t.signature = sigs.get(t.name, {}) if not rounds else {}
        # equal held-out drops (two effects both reaching the noise floor cap the drop at 1)
        # are decided by the training likelihood
        trials.sort(key=lambda t: (t.drop, t.lr), reverse=True)
        if not rounds:
            first = trials
        last = trials
        rounds.append(
            {
                "model": list(cur.model.effect_names),
                "ranked": [t.summary(at_floor, cfg.alpha) for t in trials],
            }
        )
        chosen = [t for t in trials if t.significant]
        if not chosen:
            break
        best = chosen[0]
        step = best.summary(at_floor, cfg.alpha)
        step.update(action="add", model=[*cur.model.effect_names, best.name])
        path.append(step)
        cur, cur_eval = best.fit, best.evaluation
        # backward check: is every earlier effect still needed next to the new one?
        for name in list(cur.model.effect_names):
            if name == best.name or name in start:
                continue
            rest = [e for e in cur.model.effect_names if e != name]
            reduced = wb.fit_model(wb.base_model.with_effects(*rest), warm=cur)
            lr, dof, p = lr_test(reduced, cur)
            if p >= cfg.alpha:
                red_eval = wb.evaluate(reduced, with_free_run=False)
                path.append(
                    {
                        "name": name,
                        "action": "remove",
                        "p_value": p,
                        "lr_statistic": lr,
                        "dof": dof,
                        "heldout_error_before": float(cur_eval["model_error"]),
                        "heldout_error": float(red_eval["model_error"]),
                        "model": rest,
                    }
                )
                removed.add(name)
                cur, cur_eval = reduced, red_eval
    final_names = list(cur.model.effect_names)
    selected = [s for s in path if s["action"] == "add" and s["name"] in final_names]
    return {
        "start": list(start),
        "rounds": rounds,
        "path": path,
        "selected": [
            {
                "name": s["name"],
                "p_value": s["p_value"],
                "params": s["params"],
                "heldout_error_before": s["heldout_error_before"],
                "heldout_error_after": s["heldout_error"],
                "heldout_error_drop": s["heldout_error_drop"],
                "drop_p_value": s["drop_p_value"],
                "heldout_multistep_error_before": s["heldout_multistep_error_before"],
                "heldout_multistep_error_after": s["heldout_multistep_error"],
                "noise_floor": s["noise_floor"],
            }
            for s in selected
        ],
        "removed": sorted(removed),
        "final_effects": final_names,
        "_first": first,
        "_last": last,
        "_final": cur,
        "_final_eval": cur_eval,
    }
