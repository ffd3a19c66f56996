"""The workbench engine: fit and evaluate models on one log, and run the loop.

:class:`Workbench` fits any composed model on the training windows (warm-started from a nested
fit), evaluates it on the held-out windows and runs the forward selection with a backward
check (:mod:`pcvfe_drake.workbench.selection`) and the final tests
(:mod:`pcvfe_drake.workbench.verdict`). Significance of an effect (stated in every report as
``method``): a likelihood-ratio test on the training fit, ``LR = n_eff ln(J_before / J_after)``
against chi-square with as many degrees of freedom as the effect has parameters (``n_eff``
counts one observation per training window and fitted state, because errors along one rollout
are strongly correlated), Bonferroni over the effects ranked in a round, AND a drop of the
held-out model error (the multi-step error in excess of the measurement-noise floor, see
:mod:`pcvfe_drake.workbench.compare`) of at least ``min_drop``, AND no parameter at a bound.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from pcvfe_drake.models.data import DriveData, window_starts
from pcvfe_drake.models.effects import get_effect, known_effects
from pcvfe_drake.models.estimate import FIT_STATES, FitResult, fit
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import STATE_NAMES
from pcvfe_drake.workbench.compare import evaluate, public
from pcvfe_drake.workbench.evidence import error_drop, excess_error_test
from pcvfe_drake.workbench.selection import run_selection
from pcvfe_drake.workbench.verdict import final_verdict

METHOD = (
    "forward selection with a backward check; an effect is significant on top of the current "
    "model by a likelihood-ratio test (chi-square, dof = number of effect parameters, one "
    "observation per training window and fitted state, Bonferroni over the effects of the "
    "round) at alpha={alpha:g}, AND a drop of the held-out model error (multi-step error above "
    "the noise floor) of at least {min_drop:.0%}, AND no parameter at a bound; the final model "
    "is tested for error above the noise floor (alpha/2) and residual structure (alpha/2, "
    "Bonferroni)"
)


PEAK_MU_START_FACTORS = (1.0, 0.8, 0.6)
"""Factors on the fitted base mu tried as starts when a ``friction_is_peak`` tyre is added."""


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of a diagnosis (times in seconds)."""

    fit_horizon_s: float = 1.0
    fit_burn_in_s: float = 0.25
    eval_horizon_s: float = 2.0
    eval_stride_s: float = 0.25
    signature_horizon_s: float = 0.5
    n_blocks: int = 6
    alpha: float = 0.01
    min_drop: float = 0.05
    base_params: tuple[str, ...] = ("mu",)
    max_iter: int = 15
    max_steps: int = 8
    lr_tol: float = 0.01
    """A fit stops once an accepted step raises the likelihood-ratio statistic (``n_eff`` times
    the log of the cost ratio) by less than this, when the Gauss-Newton step from there
    promises less than this too: every decision of the loop compares such statistics with
    chi-square quantiles, which a hundredth does not move. A small step that leaves more
    promised was a damped one far from the minimum: that fit is made again at ``FIT_RTOL``,
    as with ``lr_tol`` 0 (the fitter's relative tolerance throughout)."""


FIT_RTOL = 1e-7
"""The fitter's relative tolerance where ``lr_tol`` does not stop a fit."""


def gauss_newton_gain(res: FitResult) -> float:
    """The likelihood-ratio statistic (``n_eff`` times the relative cost decrease) that a
    Gauss-Newton step from ``res`` promises, from its stored residuals and Jacobian: over the
    informed parameters, less those on a bound that the step would push beyond it. Infinite
    without them."""
    jac, r = res.jacobian, res.residuals
    if jac is None or r is None or not np.all(np.isfinite(jac)):
        return float("inf")
    lo, hi = res.model.bounds()
    g = jac.T @ r  # half the cost's gradient: descent is -g
    tol = 1e-6 * (hi - lo)
    blocked = ((res.theta <= lo + tol) & (g > 0)) | ((res.theta >= hi - tol) & (g < 0))
    free = np.any(jac != 0.0, axis=0) & ~blocked
    if not free.any():
        return 0.0
    jf, gf = jac[:, free], g[free]
    step = np.linalg.lstsq(jf.T @ jf, gf, rcond=None)[0]
    return res.n_eff * max(float(gf @ step), 0.0) / max(res.cost, 1e-300)


def _steps(seconds: float, data: DriveData) -> int:
    return max(1, int(round(seconds / data.dt)))


class Workbench:
    """Fits and compares models on one drive log (the engine behind ``pcvfe diagnose``)."""

    def __init__(
        self,
        data: DriveData,
        vehicle: VehicleParams | str | None = None,
        config: DiagnoseConfig | None = None,
    ) -> None:
        self.data = data
        self.config = config or DiagnoseConfig()
        cfg = self.config
        self.base_model = WorkbenchModel(
            vehicle, base_params=cfg.base_params, contexts=data.context_names
        )
        self.h_fit = _steps(cfg.fit_horizon_s, data)
        self.h_eval = _steps(cfg.eval_horizon_s, data)
        self.train_starts = window_starts(data, self.h_fit, self.h_fit, "train", cfg.n_blocks)
        self.eval_starts = window_starts(
            data, self.h_eval, _steps(cfg.eval_stride_s, data), "heldout", cfg.n_blocks
        )
        if self.train_starts.size < 5 or self.eval_starts.size < 5:
            raise ValueError(
                f"drive log {data.source}: too few usable windows ({self.train_starts.size} "
                f"training, {self.eval_starts.size} held-out); the workbench needs stretches "
                f"of >= {cfg.eval_horizon_s:g} s at v >= 1 m/s in every time block"
            )
        self.window_group = max(1, int(round(cfg.eval_horizon_s / cfg.eval_stride_s)))
        self.n_fits = 0
        self._base: FitResult | None = None
        self._base_eval: dict | None = None

    # ------------------------------------------------------------------ fitting
    def fit_model(
        self,
        model: WorkbenchModel,
        warm: FitResult | None = None,
        fixed: dict[str, float] | None = None,
        hac_lag: int | None = None,
        starts: np.ndarray | None = None,
    ) -> FitResult:
        """Fit ``model`` on the training windows (or on the windows starting at ``starts``,
        a subset of them), warm-started from a nested fit; ``fixed`` holds parameters
        (model-wide names) at given values (``pcvfe fit --effects``); ``hac_lag``: the std
        from the Newey-West sandwich with this many lags (``fit``)."""
        self.n_fits += 1
        n_windows = (self.train_starts if starts is None else starts).size
        # the relative cost decrease that moves the LR statistic by lr_tol (n_eff as ``fit``)
        rtol = self.config.lr_tol / max(n_windows * len(FIT_STATES), 1)
        theta0 = model.initial_theta() if warm is None else model.transfer(warm.theta, warm.model)
        mask = np.array([p in (fixed or {}) for p in model.param_names])
        values = np.array([(fixed or {}).get(p, 0.0) for p in model.param_names])
        theta0[mask] = values[mask]
        candidates = []
        mu_idx = [i for i, p in enumerate(model.params) if p.effect is None and p.name[:2] == "mu"]
        for e in model.effects:
            if e.starts and (warm is None or e.name not in warm.model.effect_names):
                idx = model.effect_param_indices(e.name)
                # a tyre whose peak is mu: the linear fit's mu is no peak (it sets the
                # stiffness), so lower peaks are tried from the start as well
                factors = PEAK_MU_START_FACTORS if e.friction_is_peak else (1.0,)
                used = self.used_friction(model) if e.friction_is_peak else None
                for start in e.starts:
                    for f in factors:
                        c = theta0.copy()
                        c[idx] = start
                        c[mu_idx] = c[mu_idx] * f
                        c[mask] = values[mask]
                        candidates.append(c)
                    if used is not None:  # the peak at the largest friction the data used
                        c = theta0.copy()
                        c[idx] = start
                        c[mu_idx] = used
                        candidates.append(c)
        args = (model, self.data, self.train_starts if starts is None else starts, self.h_fit)
        common = {
            "theta0": theta0,
            "candidates": candidates,
            "max_iter": self.config.max_iter,
            "burn_in": min(_steps(self.config.fit_burn_in_s, self.data), self.h_fit - 1),
            "fixed": mask,
            "hac_lag": hac_lag,
        }
        if not self.config.lr_tol:
            return fit(*args, rtol=FIT_RTOL, **common)
        res = fit(*args, rtol=rtol, **common)
        h = res.history
        # stopped by lr_tol where the fitter's tolerance would have gone on (not at max_iter,
        # nor after a rejected step), and a small step far from the minimum: made again as the
        # fitter's tolerance makes it
        early = len(h) >= 2 and FIT_RTOL * h[-2] < h[-2] - h[-1] <= rtol * h[-2]
        if early and gauss_newton_gain(res) >= self.config.lr_tol:
            res = fit(*args, rtol=FIT_RTOL, **common)
        return res

    def used_friction(self, model: WorkbenchModel) -> np.ndarray:
        """Per base ``mu`` entry of ``model`` (one per context): 1.05 x the largest friction
        the log used in that context, the 99th percentile of ``|v psi_dot| / g`` (a start for
        a tyre whose peak is mu; within the bounds)."""
        d = self.data
        ay = np.abs(d.x[:, 3] * d.x[:, 5]) / model.vehicle.g
        out = []
        for p in model.params:
            if p.effect is None and p.name[:2] == "mu":
                rows = d.context == p.context
                level = float(np.percentile(ay[rows], 99.0)) if rows.any() else p.initial
                out.append(float(np.clip(1.05 * level, p.lower, p.upper)))
        return np.array(out)

    @property
    def baseline(self) -> FitResult:
        if self._base is None:
            self._base = self.fit_model(self.base_model)
        return self._base

    @property
    def baseline_eval(self) -> dict:
        if self._base_eval is None:
            self._base_eval = self.evaluate(self.baseline)
        return self._base_eval

    def evaluate(self, result: FitResult, with_free_run: bool = True) -> dict:
        return evaluate(
            result.model,
            result.theta,
            self.data,
            self.eval_starts,
            self.h_eval,
            self.config.n_blocks,
            with_free_run,
        )

    # ------------------------------------------------------------------ signatures
    def signatures(self, names: list[str]) -> dict[str, dict]:
        """How strongly the baseline's short-horizon residual of each effect's signature state
        is explained by the effect's regressors (uncentred multiple correlation R)."""
        data = self.data
        k = _steps(self.config.signature_horizon_s, data)
        starts = window_starts(data, k, 1, "all", self.config.n_blocks)
        if starts.size < 10:
            return {}
        err = self.base_model.errors(self.baseline.theta, data, starts, k)
        out = {}
        for name in names:
            e = get_effect(name)
            s = STATE_NAMES.index(e.signature_state)
            resid = err[:, -1, s]
            reg = e.signature_regressors(data)
            idx = starts[:, None] + np.arange(k)[None, :]
            X = reg[idx].mean(axis=1)
            beta, *_ = np.linalg.lstsq(X, resid, rcond=None)
            fitted = X @ beta
            denom = float(resid @ resid)
            r2 = float(fitted @ fitted) / denom if denom > 0 else 0.0
            r = float(np.sqrt(min(max(r2, 0.0), 1.0)))
            out[name] = {
                "state": e.signature_state,
                "regressor": e.signature_label,
                "R": r,
                "text": f"{e.signature_state} residual correlates with {e.signature_label} "
                f"(R = {r:.2f}): {name}",
            }
        return out

    # ------------------------------------------------------------------ the loop
    def at_floor(self, ev: dict) -> bool:
        """Whether a model's held-out error is within the noise (no significant excess)."""
        return excess_error_test(ev, self.data, self.window_group)["p_value"] >= self.config.alpha

    def rank(self, candidates: list[str] | None = None, start: list[str] | None = None) -> dict:
        """Forward selection with a backward check from ``start`` (see
        :mod:`pcvfe_drake.workbench.selection`), then the verdict; JSON-ready."""
        names = known_effects() if candidates is None else [get_effect(c).name for c in candidates]
        start = [get_effect(e).name for e in (start or [])]
        names = [n for n in names if n not in start]
        sel = run_selection(self, names, start, self.config.max_steps)
        self.selection = sel
        self.candidates = sel["_first"]
        final, final_eval = sel["_final"], sel["_final_eval"]
        self.final_fit, self.final_eval = final, final_eval
        alpha = self.config.alpha
        verdict = final_verdict(self, final, final_eval, sel["final_effects"], alpha)
        base_floor = self.at_floor(self.baseline_eval)
        ranked = [t.summary(base_floor if not start else False, alpha) for t in sel["_first"]]
        chosen = [s["name"] for s in sel["selected"]]
        last_round = sel["rounds"][-1]["ranked"] if len(sel["rounds"]) > 1 else []
        return {
            "method": METHOD.format(alpha=alpha, min_drop=self.config.min_drop),
            "ranked_effects": ranked,
            "selected": sel["selected"],
            "selection": {k: v for k, v in sel.items() if not k.startswith("_")},
            "best": chosen[0] if chosen else None,
            "remaining": [
                {
                    "name": r["name"],
                    "on_top_of": " + ".join(sel["final_effects"]) or "baseline",
                    "significant": r["significant"],
                    "p_value": r["p_value"],
                    "heldout_error_drop": r["heldout_error_drop"],
                }
                for r in last_round
            ],
            "remaining_significant": chosen[1:],
            "final": {
                "effects": sel["final_effects"],
                "params": final.params_dict(),
                "heldout_error": final_eval["model_error"],
                "heldout_multistep_error": final_eval["multistep_error"],
                "noise_floor": final_eval["noise_floor"],
            },
            "unexplained_structure": verdict["kind"] == "outside_library",
            "final_error_to_noise_floor": verdict["error_to_noise_floor"],
            "verdict": verdict,
        }

    def add(self, effects: list[str]) -> dict:
        """Refit with ``effects`` added; before/after numbers (JSON-ready)."""
        names = [get_effect(e).name for e in effects]
        model = self.base_model.with_effects(*names)
        res = self.fit_model(model, warm=self.baseline)
        ev = self.evaluate(res)
        drop = error_drop(self.baseline_eval, ev)
        dof = model.n_params - self.base_model.n_params
        lr = max(0.0, self.baseline.n_eff * float(np.log(self.baseline.cost / res.cost)))
        self.added_fit, self.added_eval = res, ev
        return {
            "effects": names,
            "params": res.params_dict(),
            "heldout": public(ev),
            "heldout_error": ev["model_error"],
            "heldout_multistep_error": ev["multistep_error"],
            "error_drop": drop,
            "lr_statistic": lr,
            "p_value": float(chi2.sf(lr, dof)) if dof > 0 else 1.0,
        }

    def baseline_summary(self) -> dict:
        ev = self.baseline_eval
        label = next(iter(ev["fit_percent_kstep"]))
        for key in ev["fit_percent_kstep"]:
            if abs(float(key[:-1]) - self.config.fit_horizon_s) < 1e-9:
                label = key
        return {
            "params": self.baseline.params_dict(),
            "fit_percent": ev["fit_percent_kstep"][label],
            "fit_percent_horizon": label,
            "heldout_error": ev["model_error"],
            "heldout_multistep_error": ev["multistep_error"],
            "noise_floor": ev["noise_floor"],
            "heldout": public(ev),
            "train_cost": self.baseline.cost,
        }
