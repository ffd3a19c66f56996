"""The verdict after the loop: explained, or something outside the library remains, and where.

The final model of the selection is tested with
:func:`~pcvfe_drake.workbench.evidence.excess_error_test` (held-out error above the noise floor)
and :func:`~pcvfe_drake.workbench.evidence.residual_structure` (whiteness and input
cross-correlation of its residuals); all p-values are compared with ``alpha / (number of
tests)`` (Bonferroni), so a log that the model explains is called "explained" with probability
at least ``1 - alpha``. A base parameter (e.g. mu) that ends on its bound is evidence too.

"Where" comes from the final model's held-out windows: the per-window excess error (whitened
MSE minus the window's noise floor) is averaged per bin of speed, lateral acceleration,
steering rate, acceleration command, drive mode and context; a bin is named when its mean
excess is at least twice the log's and more than 2.58 standard errors above it. The time and
place come from the same windows: those with at least twice the log's mean excess, joined into
spans where they follow within two window lengths; the span holding the largest part of the
excess is named with its time, its place on the course (the mean position) and its context.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import norm

from pcvfe_drake.models.data import DriveData
from pcvfe_drake.models.effects import get_effect
from pcvfe_drake.models.estimate import FIT_STATES
from pcvfe_drake.vehicle.single_track import STATE_NAMES
from pcvfe_drake.workbench.evidence import excess_error_test, residual_structure
from pcvfe_drake.workbench.stability import stand_ins as unstable_effects

REGIMES = {
    "speed": "m/s",
    "lateral_accel": "m/s^2",
    "steering_rate": "rad/s",
    "accel_command": "m/s^2",
}


def regime_values(data: DriveData, mid: np.ndarray) -> dict[str, np.ndarray]:
    """Operating-regime values at the window mid-points ``mid``."""
    x, u = data.x[mid], data.u[mid]
    return {
        "speed": x[:, 3],
        "lateral_accel": np.abs(x[:, 3] * x[:, 5]),
        "steering_rate": np.abs(u[:, 0]),
        "accel_command": u[:, 1],
    }


def drive_mode(accel: np.ndarray) -> np.ndarray:
    """0 accelerating, 1 coasting, 2 braking (command beyond +-0.1 m/s^2)."""
    return np.where(accel > 0.1, 0, np.where(accel < -0.1, 2, 1))


MODES = ("accelerating", "coasting", "braking")


def range_edges(values: np.ndarray, k: int = 4, min_share: float = 0.08) -> np.ndarray:
    """Bin edges over the data's own range (2nd-98th percentile, equal width), with bins that
    would hold fewer than ``min_share`` of the samples merged into their neighbours; a narrow
    range gives fewer bins, never empty ones."""
    v = np.asarray(values, float)
    lo, hi = np.percentile(v, [2, 98]) if v.size else (0.0, 0.0)
    if not np.isfinite(lo) or hi - lo <= 1e-9 * max(1.0, abs(hi)):
        return np.array([-np.inf, np.inf])
    inner = list(np.linspace(lo, hi, k + 1)[1:-1])
    edges = [-np.inf, *inner, np.inf]
    while len(edges) > 2:
        counts = np.histogram(v, bins=np.array(edges))[0]
        small = np.flatnonzero(counts < min_share * v.size)
        if small.size == 0:
            break
        b = int(small[np.argmin(counts[small])])
        # drop the inner edge shared with the smaller neighbour
        if b == 0:
            del edges[1]
        elif b == len(counts) - 1:
            del edges[-2]
        else:
            del edges[b if counts[b - 1] <= counts[b + 1] else b + 1]
    return np.array(edges)


def bin_label(lo: float, hi: float, unit: str) -> str:
    if not np.isfinite(lo) and not np.isfinite(hi):
        return "all"
    if not np.isfinite(lo):
        return f"below {hi:.3g} {unit}"
    if not np.isfinite(hi):
        return f"above {lo:.3g} {unit}"
    return f"{lo:.3g}-{hi:.3g} {unit}"


def localise(ev: dict, starts: np.ndarray, data: DriveData, group: int) -> dict:
    """Per-bin mean excess error of the windows (see module docstring); JSON-ready."""
    excess = np.asarray(ev["_mse_w"]) - np.asarray(ev["_floor_w"])
    horizon = ev["_err"].shape[1]
    mid = starts + horizon // 2
    overall = float(np.mean(excess))
    scale = float(np.std(excess)) * np.sqrt(max(group, 1))  # overlapping windows
    groups: dict[str, list[dict]] = {}

    def add(kind, label, sel):
        n = int(sel.sum())
        if n == 0:
            return
        m = float(np.mean(excess[sel]))
        se = scale / np.sqrt(n)
        groups.setdefault(kind, []).append(
            {"bin": label, "n": n, "excess": m, "se": se, "z": (m - overall) / max(se, 1e-12)}
        )

    for kind, values in regime_values(data, mid).items():
        edges = range_edges(values)
        idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, edges.size - 2)
        for b in range(edges.size - 1):
            add(kind, bin_label(edges[b], edges[b + 1], REGIMES[kind]), idx == b)
    mode = drive_mode(data.u[mid, 1])
    for m, label in enumerate(MODES):
        add("drive_mode", label, mode == m)
    if len(data.context_names) > 1:
        ctx = data.context[starts]
        for c, label in enumerate(data.context_names):
            add("context", f"on {label}", ctx == c)
    hot = []
    for kind, rows in groups.items():
        if len(rows) < 2:
            continue
        for r in rows:
            if r["excess"] >= 2.0 * max(overall, 1e-12) and r["z"] > 2.576:
                hot.append({"kind": kind, **r})
    hot.sort(key=lambda r: r["excess"], reverse=True)
    span = hot_span(excess, starts, horizon, data)
    idx = list(FIT_STATES)
    err = ev["_err"][:, :, idx] / data.sigma[idx]
    per_state = np.mean(err**2, axis=(0, 1)) - 1.0
    worst = STATE_NAMES[idx[int(np.argmax(per_state))]]
    return {
        "overall_excess": overall,
        "bins": groups,
        "concentrated": hot[:4],
        "span": span,
        "worst_state": worst,
        "excess_per_state": {STATE_NAMES[i]: float(e) for i, e in zip(idx, per_state, strict=True)},
    }


def hot_span(excess: np.ndarray, starts: np.ndarray, horizon: int, data: DriveData) -> dict | None:
    """The time span of windows holding the largest part of the excess error (module
    docstring): ``t0_s``, ``t1_s``, ``share`` of the log's positive excess, mean position
    ``sx_m``, ``sy_m`` and majority ``context``; None when no window has twice the mean."""
    excess = np.asarray(excess, dtype=float)
    positive = np.maximum(excess, 0.0)
    total = float(positive.sum())
    overall = float(np.mean(excess)) if excess.size else 0.0
    order = np.argsort(starts)
    hot = order[excess[order] >= 2.0 * max(overall, 1e-12)]
    if hot.size == 0 or total <= 0:
        return None
    breaks = np.flatnonzero(np.diff(starts[hot]) > 2 * horizon) + 1
    best = max(np.split(hot, breaks), key=lambda w: float(positive[w].sum()))
    mid = starts[best] + horizon // 2
    ctx = np.bincount(data.context[mid], minlength=len(data.context_names))
    return {
        "t0_s": float(data.t[starts[best].min()]),
        "t1_s": float(data.t[min(starts[best].max() + horizon, data.n - 1)]),
        "share": float(positive[best].sum() / total),
        "sx_m": float(np.mean(data.x[mid, 0])),
        "sy_m": float(np.mean(data.x[mid, 1])),
        "context": data.context_names[int(np.argmax(ctx))],
        "windows": int(best.size),
    }


def span_phrase(span: dict | None, contexts: int) -> str:
    """``"the largest part of the held-out excess (37%) at t 40.1-52.3 s, around (12, -30) m, on
    sand"`` ("" without a span)."""
    if span is None:
        return ""
    on = f", on {span['context']}" if contexts > 1 else ""
    return (
        f"the largest part of the held-out excess ({span['share']:.0%}) at t {span['t0_s']:.1f}-"
        f"{span['t1_s']:.1f} s, around ({span['sx_m']:.0f}, {span['sy_m']:.0f}) m{on}"
    )


def where_sentence(where: dict, contexts: int = 1) -> str:
    """Where the error remains: the regimes it concentrates in, the worst state and the time
    and place of the span with the largest part of it."""
    hot = where["concentrated"]
    state = f"the worst-predicted state is {where['worst_state']}"
    span = span_phrase(where.get("span"), contexts)
    if span:
        state += f"; {span}"
    if not hot:
        return f"errors spread over all operating regimes; {state}"
    seen, parts = set(), []
    for r in hot:
        if r["kind"] in seen:
            continue
        seen.add(r["kind"])
        label = r["bin"]
        if r["kind"] in REGIMES:
            label = f"{r['kind'].replace('_', ' ')} {label}"
        elif r["kind"] == "drive_mode":
            label = f"in {label}"
        parts.append(f"{label} ({r['excess'] / max(where['overall_excess'], 1e-12):.1f}x)")
    return f"errors concentrate at {' and '.join(parts[:3])}; {state}"


def final_verdict(wb, fit, ev, selected: list[str], alpha: float) -> dict:
    """Test the final model and word the verdict (JSON-ready).

    Half of ``alpha`` goes to the excess-error test, the other half is shared (Bonferroni) by
    the residual-structure tests. When a test fails, a selected effect can be a *stand-in*
    for the missing law: it lowers the error but is not its cause, and the verdict does not
    name it. Two rules find stand-ins: the effect's own signature state still fails a
    residual test (it does not explain its own state), or its parameters are not the same
    over the operating range (:func:`pcvfe_drake.workbench.stability.stand_ins`, a Chow-type
    test at ``alpha``; run only when a test fails and effects would otherwise be named)."""

    data = wb.data
    resid = residual_structure(fit.model, fit.theta, data, wb.config.n_blocks)
    n_resid = max(len(resid["tests"]), 1)
    z_excess = float(norm.isf(alpha / 2.0))
    excess = excess_error_test(ev, data, wb.window_group, z_crit=z_excess)
    tests = [
        (
            "excess_error",
            "held-out error above the noise floor",
            excess["p_value"],
            alpha / 2.0,
            "",
        )
    ]
    for t in resid["tests"]:
        what = (
            f"{t['state']} residual autocorrelated"
            if t["kind"] == "autocorrelation"
            else f"{t['state']} residual correlates with {t['input']} (lag {t['lag']})"
        )
        tests.append((t["kind"], what, t["p_value"], alpha / 2.0 / n_resid, t["state"]))
    failed = [(k, w, p, th, st) for k, w, p, th, st in tests if p < th]
    base_bound = [
        name
        for name, q in fit.params_dict().items()
        if q["at_bound"] and fit.model.params[fit.model.param_names.index(name)].effect is None
    ]
    failed_states = {st for *_, st in failed if st}
    stand_ins = [e for e in selected if get_effect(e).signature_state in failed_states]
    named = [e for e in selected if e not in stand_ins]
    stand_in_evidence = {
        e: f"{get_effect(e).signature_state} residual still fails a test" for e in stand_ins
    }
    stability = None
    if (failed or base_bound) and named:
        stability = unstable_effects(wb, fit, named, alpha)
        stand_ins += stability["stand_ins"]
        stand_in_evidence.update(stability["evidence"])
        named = [e for e in named if e not in stand_ins]
    where = localise(ev, wb.eval_starts, data, wb.window_group)
    evidence = [f"{w} (p = {p:.2g})" for _, w, p, _, _ in failed]
    if base_bound:
        evidence.append(f"{', '.join(base_bound)} at a bound")
    ratio = excess["model_error"] / max(excess["noise_floor"], 1e-12)
    if failed or base_bound:
        kind = "outside_library"
        head = "something outside the library remains"
        if named:
            head += f" after {' + '.join(named)}"
        text = f"{head}: {'; '.join(evidence)}; {where_sentence(where, len(data.context_names))}"
        if stand_ins:
            many = len(stand_ins) > 1
            text += (
                f" (the loop's {' + '.join(stand_ins)} lower{'' if many else 's'} the error but "
                f"{'are stand-ins' if many else 'is a stand-in'}, not the cause: "
                f"{'; '.join(stand_in_evidence[e] for e in stand_ins)})"
            )
    else:
        kind = "explained"
        limit = excess["detection_limit"] / max(excess["noise_floor"], 1e-12)
        at = (
            f"at the noise floor: held-out model error {ratio:.2g} x the noise floor, "
            f"no test finds structure; this log detects a model error above ~{limit:.2g} x "
            "the noise floor"
        )
        by = " + ".join(named)
        text = f"explained by {by} ({at})" if by else f"explained ({at})"
    return {
        "kind": kind,
        "text": text,
        "effects": named,
        "stand_ins": stand_ins,
        "stand_in_evidence": stand_in_evidence,
        "stability": stability,
        "where": (
            where_sentence(where, len(data.context_names)) if kind == "outside_library" else ""
        ),
        "evidence": evidence,
        "tests": [
            {"test": k, "what": w, "p_value": p, "threshold": th, "failed": bool(p < th)}
            for k, w, p, th, _ in tests
        ],
        "alpha": alpha,
        "excess_error": excess,
        "residual_structure": resid,
        "context_bias": resid.get("context_bias", {}),
        "localisation": where,
        "base_params_at_bound": base_bound,
        "error_to_noise_floor": float(ratio),
    }
