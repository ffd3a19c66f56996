"""Peers of the model-discrepancy workbench: PySINDy and SysIdentPy on the planted-effect logs.

Logs: ``pcvfe_drake.workbench.synth`` (as ``workbench_proof_sweep.py``: 90 s at 20 Hz, GNSS/INS
noise, substeps 2): a clean log, each named effect alone (drag, rolling_resistance,
steering_lag, input_delay, tire_saturation) and each of their 10 pairs (``--triples``: the 10
triples too), the set the workbench's proof sweep uses. Every method
sees the first 70 % of a log (training) and is scored on the last 30 % (held out).

Methods, each as its users would run it on the discrepancy of the known ST model (nominal
vehicle parameters), on the dynamic states D = (delta, v, psi_dot, beta) with the commands
u = (steer_rate, accel):

* **workbench** (ours): ``diagnose`` on the training part, its selection loop starting from
  the bare model; identified = the loop selected exactly the planted effect(s); false
  discovery = any selected effect that was not planted (any at all on the clean log).
* **PySINDy** (``pysindy.SINDy``): target = the measured state derivative
  (``SmoothedFiniteDifference``, PySINDy's recommendation for noisy data) minus the ST model's
  derivative; library = polynomials of degree 2 plus Fourier (sin, cos, one frequency) of
  (D, u); optimiser STLSQ with ``normalize_columns=True`` (the library's columns differ in
  scale by orders of magnitude). Its threshold is tuned as PySINDy's docs advise (a sweep),
  here by a stated rule: the smallest threshold of ``THRESHOLDS`` that selects no term on a
  clean log of another seed (seed + 100), i.e. calibrated to no false discovery on clean data.
* **SysIdentPy** (``FROLS``, NARMAX): target per state in D = the one-step residual
  x(k+1) - RK4_ST(x(k), u(k)); regressors: the residual's own lag 1, D and u at lag 1, the
  acceleration command at lags 1-4 (a dead time up to 0.2 s), polynomial degree 2; FROLS with
  ``order_selection=True``. Information criterion tuned by the same rule as PySINDy: the first of
  AIC (its default), BIC that selects no physical term on the clean calibration log. Terms
  with the residual's own lag r(k-1) (alone or in products) model the measurement noise (the
  one-step residual of noisy states is correlated with its predecessor) and are not counted
  as discoveries; they stay in the model for the rollouts.

Identification rule (the same for both peers): an effect is identified when the discovered
model contains its signature term: drag a v^2 term in the v equation; rolling resistance a
constant in the v equation (with no v^2 term for the peers it is called rolling only if the
constant dominates); steering lag any term in the delta equation; input delay a term in the v
equation with the acceleration command (for SysIdentPy at lag >= 2, a delay; PySINDy has no
lags); tire saturation any term in the psi_dot or beta equation. Extra terms are counted.
False discoveries on the clean log = the number of terms selected.

Held-out error (all three the same way): rollouts of 2 s (the workbench's evaluation horizon)
from the measured states every 0.25 s of the held-out 30 %, with the measured commands; RMS of
the errors divided by the log's noise scales over (delta, v, psi, psi_dot, beta), as the
workbench's headline; ``none`` is the ST model alone. Time: the fit (and for the workbench the
whole ``diagnose``), wall clock on a shared machine, in this run.

Usage: python benchmarks/peers_workbench.py [--quick] [--triples] [--seed S].
Last stdout line: JSON.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import itertools
import json
import os
import time
import warnings

import numpy as np

from pcvfe_drake.models.data import prepare
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.vehicle.single_track import (
    BETA,
    DELTA,
    NX,
    PSI,
    PSI_DOT,
    V,
    rk4_step,
    st_dynamics,
    wrap_angle,
)
from pcvfe_drake.workbench import synth
from pcvfe_drake.workbench.report import diagnose

D = (DELTA, V, PSI_DOT, BETA)
D_NAMES = ("delta", "v", "psi_dot", "beta")
SCORED = (DELTA, V, PSI, PSI_DOT, BETA)
THRESHOLDS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0)
HORIZON_S, STRIDE_S, TRAIN_FRACTION = 2.0, 0.25, 0.7
ACCEL_LAGS = 4
DIVERGED = np.array([1.6, 100.0, 10.0, 1.6])
"""A rollout past these |delta| [rad], |v| [m/s], |psi_dot| [rad/s], |beta| [rad] has diverged."""
ORIGINAL = ("drag", "rolling_resistance", "steering_lag", "input_delay", "tire_saturation")
LOGS = {
    "clean": [],
    **{e: [e] for e in ORIGINAL},
    **{f"{a}+{b}": [a, b] for a, b in itertools.combinations(ORIGINAL, 2)},
}
"""The clean log, each original effect alone and every pair of them (the loop's pair set in
``workbench_proof_sweep.py``); ``--triples`` adds every triple."""


def _truth(effects):
    kw = {}
    for e in effects:
        t = synth.PLANTED[e][0]
        for f in ("CdA", "c_rr", "steer_tau", "accel_delay", "mu_peak"):
            if getattr(t, f) != getattr(synth.Truth(), f):
                kw[f] = getattr(t, f)
    return synth.Truth(**kw)


def _heldout_starts(n, dt):
    h, stride = int(round(HORIZON_S / dt)), int(round(STRIDE_S / dt))
    return np.arange(int(TRAIN_FRACTION * n) + ACCEL_LAGS, n - h - 1, stride), h


def _diverged(pred) -> int:
    """Rollout windows that left finite values."""
    return int(np.sum(~np.all(np.isfinite(pred[:, :, :NX]), axis=(1, 2))))


def _score(pred, data, starts, h):
    idx = starts[:, None] + np.arange(1, h + 1)[None, :]
    err = pred[:, 1:, :NX] - data.x[idx]
    err[:, :, PSI] = wrap_angle(err[:, :, PSI])
    w = err[:, :, SCORED] / data.sigma[list(SCORED)]
    finite = np.all(np.isfinite(w), axis=(1, 2))
    if not finite.all():
        print(f"  {np.sum(~finite)} of {finite.size} rollouts diverged (not scored)", flush=True)
    return float(np.sqrt(np.mean(w[finite] ** 2))) if finite.any() else float("inf")


def _rollout(data, starts, h, vp, step_fn):
    """Batched rollouts: x(k+1) = step_fn(x(k), k-index array, history)."""
    x = data.x0[starts].copy()
    out = np.empty((starts.size, h + 1, NX))
    out[:, 0] = x
    for j in range(h):
        x = step_fn(x, starts + j, out, j)
        out[:, j + 1] = x
    return out


# ------------------------------------------------------------------ PySINDy
def _sindy_fit(ps, data, vp, n_train, threshold):
    x, u = data.x[:n_train], data.u[:n_train]
    xd = ps.SmoothedFiniteDifference()(x[:, list(D)], data.t[:n_train])
    target = xd - st_dynamics(x, u, vp)[:, list(D)]
    lib = ps.PolynomialLibrary(degree=2) + ps.FourierLibrary(n_frequencies=1)
    model = ps.SINDy(
        feature_library=lib,
        optimizer=ps.STLSQ(threshold=threshold, normalize_columns=True),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(x[:, list(D)], t=data.dt, x_dot=target, u=u, feature_names=[*D_NAMES, "us", "ua"])
    return model


def _sindy_terms(model):
    names = model.get_feature_names()
    coef = model.coefficients()
    return {D_NAMES[i]: [names[j] for j in np.flatnonzero(coef[i])] for i in range(len(D_NAMES))}


def _sindy_rollout(model, data, starts, h, vp):
    dt = data.dt

    def f(x, u):
        # A diverged window (non-finite or past DIVERGED) stays NaN and is counted by _score;
        # the others go on.
        d = np.full_like(x, np.nan)
        ok = np.all(np.isfinite(x), axis=1) & np.all(np.abs(x[:, list(D)]) < DIVERGED, axis=1)
        with np.errstate(all="ignore"):
            d[ok] = st_dynamics(x[ok], u[ok], vp)
            d[np.ix_(ok, list(D))] += model.predict(x[ok][:, list(D)], u=u[ok])
        return d

    def step(x, k, out, j):
        u = data.u[k]
        k1 = f(x, u)
        k2 = f(x + dt / 2 * k1, u)
        k3 = f(x + dt / 2 * k2, u)
        k4 = f(x + dt * k3, u)
        return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    return _rollout(data, starts, h, vp, step)


# ------------------------------------------------------------------ SysIdentPy
def _narx_inputs(data):
    """Input matrix of the NARX models: D (4), u (2); the accel lags come from xlag."""
    return np.column_stack([data.x[:, list(D)], data.u])


def _one_step_residual(data, vp):
    nxt = rk4_step(data.x[:-1], data.u[:-1], vp, data.dt)
    r = data.x[1:] - nxt
    r[:, PSI] = wrap_angle(r[:, PSI])
    return np.vstack([np.zeros((1, NX)), r])  # r[k] = x(k) - RK4(x(k-1), u(k-1))


def _sysid_fit(sy, data, vp, n_train, criterion):
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS

    X = _narx_inputs(data)[:n_train]
    R = _one_step_residual(data, vp)[:n_train]
    xlag = [[1], [1], [1], [1], [1], list(range(1, ACCEL_LAGS + 1))]
    models = []
    for i in D:
        m = FROLS(
            order_selection=True,
            info_criteria=criterion,
            ylag=1,
            xlag=xlag,
            basis_function=Polynomial(degree=2),
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m.fit(X=X, y=R[:, [i]])
        models.append(m)
    return models


_SIG_NAMES = ("r", *D_NAMES, "us", "ua")


def _term_name(row):
    parts = []
    for code in row:
        code = int(code)
        if code == 0:
            continue
        parts.append(f"{_SIG_NAMES[code // 1000 - 1]}(k-{code % 1000})")
    return "*".join(parts) if parts else "1"


def _sysid_terms(models):
    return {D_NAMES[i]: [_term_name(r) for r in m.final_model] for i, m in enumerate(models)}


def _physical(terms):
    """Terms free of the residual's own lag r (those model the measurement noise: the one-step
    residual of noisy states is correlated with its previous value): what counts as a
    discovery for SysIdentPy."""
    return {k: [t for t in v if "r(k-" not in t] for k, v in terms.items()}


def _sysid_rollout(models, data, starts, h, vp):
    X = _narx_inputs(data)
    R = _one_step_residual(data, vp)
    # Per window: signal histories (measured before the start, predicted after).
    # Per window: the inputs' history (measured before the start, predicted after), newest
    # last, and the residual at the start (the NARX's own lag).
    hist_x = np.stack([X[starts + j] for j in range(-ACCEL_LAGS - 1, 0)], axis=1)  # (W, L+1, 6)
    hist_r = R[starts][:, list(D)]

    def regress(row, r_prev, hx):
        val = np.ones(hx.shape[0])
        for code in row:
            code = int(code)
            if code == 0:
                continue
            sig, lag = code // 1000, code % 1000
            val = val * (r_prev if sig == 1 else hx[:, -lag, sig - 2])
        return val

    def step(x, k, out, j):
        nonlocal hist_x, hist_r
        nxt = rk4_step(x, data.u[k], vp, data.dt)
        cur = np.column_stack([x[:, list(D)], data.u[k]])
        hx = np.concatenate([hist_x[:, 1:], cur[:, None, :]], axis=1)
        new_r = np.empty((x.shape[0], len(D)))
        for i, m in enumerate(models):
            theta = np.asarray(m.theta).ravel()
            new_r[:, i] = sum(
                c * regress(row, hist_r[:, i], hx)
                for c, row in zip(theta, m.final_model, strict=True)
            )
        hist_x, hist_r = hx, new_r
        nxt[:, list(D)] += new_r
        return nxt

    return _rollout(data, starts, h, vp, step)


# ------------------------------------------------------------------ rules
def _identified(effect, terms, tool):
    eq = terms
    if effect == "drag":
        return any("v^2" in t or t in ("v v", "v(k-1)*v(k-1)") for t in eq["v"])
    if effect == "rolling_resistance":
        return "1" in eq["v"]
    if effect == "steering_lag":
        return bool(eq["delta"])
    if effect == "input_delay":
        if tool == "sysidentpy":
            return any(f"ua(k-{lag})" in t for t in eq["v"] for lag in range(2, ACCEL_LAGS + 1))
        return any("ua" in t for t in eq["v"])
    if effect == "tire_saturation":
        return bool(eq["psi_dot"] or eq["beta"])
    raise ValueError(effect)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="clean, drag and input_delay only")
    ap.add_argument("--triples", action="store_true", help="also every triple of effects")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    logs_all = dict(LOGS)
    if args.triples:
        logs_all.update({"+".join(c): list(c) for c in itertools.combinations(ORIGINAL, 3)})
    vp = load_vehicle(None)
    peers, missing = {}, {}
    for mod, dist in (("pysindy", "pysindy"), ("sysidentpy", "sysidentpy")):
        try:
            peers[mod] = importlib.import_module(mod)
        except Exception as exc:
            missing[mod] = f"{dist} not installed ({type(exc).__name__}); `make bench` installs it"
            print(f"PEER MISSING: {missing[mod]}", flush=True)
    names = ["clean", "drag", "input_delay"] if args.quick else list(logs_all)
    truths = [_truth(logs_all[n]) for n in names]
    logs = synth.simulate_truths(truths, duration_s=90.0, rate_hz=20.0, seed=args.seed, substeps=2)
    calib = prepare(
        synth.simulate_truths([synth.Truth()], duration_s=90.0, seed=args.seed + 100, substeps=2)[
            0
        ],
        "calibration",
    )
    n_cal = int(TRAIN_FRACTION * calib.n)
    tuning = {}
    if "pysindy" in peers:
        ps = peers["pysindy"]
        for th in THRESHOLDS:
            nterms = sum(
                len(v) for v in _sindy_terms(_sindy_fit(ps, calib, vp, n_cal, th)).values()
            )
            print(
                f"PySINDy calibration: threshold {th}: {nterms} terms on the clean log", flush=True
            )
            if nterms == 0:
                break
        tuning["pysindy_threshold"] = th
    if "sysidentpy" in peers:
        sy = peers["sysidentpy"]
        for crit in ("aic", "bic"):
            terms = _sysid_terms(_sysid_fit(sy, calib, vp, n_cal, crit))
            extra = sum(len(v) for v in _physical(terms).values())
            print(f"SysIdentPy calibration: {crit}: {extra} physical terms on clean", flush=True)
            if extra == 0:
                break
        tuning["sysidentpy_criterion"] = crit

    rows = []
    for name, df in zip(names, logs, strict=True):
        planted = logs_all[name]
        data = prepare(df, name)
        n_train = int(TRAIN_FRACTION * data.n)
        starts, h = _heldout_starts(data.n, data.dt)
        row = {"log": name, "planted": planted}
        t0 = time.perf_counter()
        report, wb = diagnose(prepare(df.iloc[:n_train].reset_index(drop=True), name))
        row["workbench_s"] = time.perf_counter() - t0
        selected = list(report["final"]["effects"])
        row["workbench_significant"] = selected
        row["workbench_identified"] = bool(planted) and set(selected) == set(planted)
        row["workbench_false"] = len(set(selected) - set(planted))
        fit = wb.final_fit
        base_pred = wb.baseline.model.simulate(wb.baseline.theta, data, starts, h)
        row["none_heldout"] = _score(
            _rollout(data, starts, h, vp, lambda x, k, o, j, d=data: rk4_step(x, d.u[k], vp, d.dt)),
            data,
            starts,
            h,
        )
        row["workbench_baseline_heldout"] = _score(base_pred, data, starts, h)
        row["workbench_heldout"] = _score(
            fit.model.simulate(fit.theta, data, starts, h), data, starts, h
        )
        if "pysindy" in peers:
            t0 = time.perf_counter()
            model = _sindy_fit(peers["pysindy"], data, vp, n_train, tuning["pysindy_threshold"])
            row["pysindy_s"] = time.perf_counter() - t0
            terms = _sindy_terms(model)
            row["pysindy_terms"] = terms
            row["pysindy_nterms"] = sum(len(v) for v in terms.values())
            row["pysindy_identified"] = bool(planted) and all(
                _identified(p, terms, "pysindy") for p in planted
            )
            pred = _sindy_rollout(model, data, starts, h, vp)
            row["pysindy_heldout"] = _score(pred, data, starts, h)
            row["pysindy_diverged_windows"] = _diverged(pred)
        if "sysidentpy" in peers:
            t0 = time.perf_counter()
            models = _sysid_fit(
                peers["sysidentpy"], data, vp, n_train, tuning["sysidentpy_criterion"]
            )
            row["sysidentpy_s"] = time.perf_counter() - t0
            terms = _sysid_terms(models)
            row["sysidentpy_terms"] = terms
            row["sysidentpy_nterms"] = sum(len(v) for v in _physical(terms).values())
            row["sysidentpy_identified"] = bool(planted) and all(
                _identified(p, _physical(terms), "sysidentpy") for p in planted
            )
            pred = _sysid_rollout(models, data, starts, h, vp)
            row["sysidentpy_heldout"] = _score(pred, data, starts, h)
            row["sysidentpy_diverged_windows"] = _diverged(pred)
        rows.append(row)
        print(json.dumps(row), flush=True)

    result = {
        "benchmark": "peers_workbench",
        "quick": args.quick,
        "seed": args.seed,
        "peers_missing": missing,
        "peer_versions": {m: importlib.metadata.version(m) for m in peers},
        "tuning": tuning,
        "cpu_count": os.cpu_count(),
        "load_avg_1min": os.getloadavg()[0],
        "rows": rows,
    }
    for tool in ("workbench", "pysindy", "sysidentpy"):
        key = f"{tool}_identified"
        planted_rows = [r for r in rows if r["planted"] and key in r]
        if planted_rows:
            result[f"{tool}_identified"] = (
                f"{sum(r[key] for r in planted_rows)}/{len(planted_rows)}"
            )
            for k, label in ((1, "alone"), (2, "pairs"), (3, "triples")):
                sub = [r for r in planted_rows if len(r["planted"]) == k]
                if sub:
                    result[f"{tool}_identified_{label}"] = f"{sum(r[key] for r in sub)}/{len(sub)}"
            if tool == "workbench":
                result["workbench_false_discoveries"] = sum(r["workbench_false"] for r in rows)
            else:
                clean = [r for r in rows if not r["planted"] and f"{tool}_nterms" in r]
                result[f"{tool}_terms_on_clean"] = sum(r[f"{tool}_nterms"] for r in clean)
        scored = [r for r in rows if r["planted"] and f"{tool}_heldout" in r]
        if scored:
            result[f"{tool}_heldout_median"] = float(
                np.median([r[f"{tool}_heldout"] for r in scored])
            )
            better = sum(r[f"{tool}_heldout"] < r["none_heldout"] for r in scored)
            result[f"{tool}_better_than_st"] = f"{better}/{len(scored)}"
        if f"{tool}_s" in rows[0]:
            result[f"{tool}_s_median"] = float(np.median([r[f"{tool}_s"] for r in rows]))
    if "pysindy_s_median" in result:
        result["ratio_workbench_over_pysindy_time"] = (
            result["workbench_s_median"] / result["pysindy_s_median"]
        )
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
