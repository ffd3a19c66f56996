"""The report's pictures: where the model fails, before (baseline) and after (the final model).

Each function draws one PNG into a folder and returns its file name. Inputs are the report
dict and the :class:`~pcvfe_drake.workbench.ranking.Workbench` that produced it. Every picture
has a caption (:data:`CAPTIONS`) that says what it shows and what to look for: a reader who
has not built the workbench should know which part of a plot carries the finding.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pcvfe_drake.models.data import block_ids, heldout_blocks, window_starts
from pcvfe_drake.models.estimate import FIT_STATES
from pcvfe_drake.vehicle.single_track import INPUT_NAMES, STATE_NAMES
from pcvfe_drake.workbench.compare import noise_rollouts
from pcvfe_drake.workbench.verdict import localise

DPI = 80

CAPTIONS = {
    "selection_path.png": (
        "The loop, step by step: the held-out model error after each effect was added or "
        "dropped, against the noise floor (dashed). Look for a drop at every step, and how far "
        "the last point stays above the floor: that gap is what no library effect explains."
    ),
    "error_over_log.png": (
        "Model error above the noise over the whole log: baseline (blue) and final model "
        "(red); shading marks the contexts, hatching the held-out blocks. Look for where the "
        "red line stays high: the time, and the context, where the error remains."
    ),
    "error_map.png": (
        "Where on the course: left, where the baseline failed; right, what remains with the "
        "final model, on the same colour scale. Look for dark points on the right: the places "
        "(bends, a terrain) the final model still gets wrong."
    ),
    "regimes.png": (
        "Excess error per operating regime (speed, lateral acceleration, steering rate, "
        "acceleration command, drive mode), baseline and final model, with 99 % intervals. "
        "Look for a final-model bar well above its neighbours: the regime where the error "
        "remains."
    ),
    "bias.png": (
        "Residual bias of the final model's 0.2 s predictions per state (left) and per context "
        "(right), in units of the noise, with 99 % intervals. Look for intervals that miss "
        "zero; a bias that differs between contexts points to the friction or a terrain effect."
    ),
    "cross_correlation.png": (
        "Correlation of the final model's residuals with each input over the lag; grey: the "
        "99 % band of residuals the inputs do not explain. Look for curves leaving the band, "
        "at positive lags (input leading): an input whose effect the model gets wrong or late."
    ),
    "overlay.png": (
        "Measured states (black) and the free-run predictions of the baseline (blue) and the "
        "final model (red) over the held-out blocks. Look for where red leaves black (the "
        "error that remains); the gap between blue and red is what the added effects explain."
    ),
    "residual_autocorr.png": (
        "One-step residual autocorrelation per state, baseline and final model; grey: the 99 % "
        "band of white residuals. Look for the final model's curves inside the band: what stays "
        "outside is dynamics the model lacks."
    ),
    "ranking.png": (
        "First round: how much each library effect alone lowers the held-out model error "
        "(green: significant). Look for the effects the loop could choose from; a long grey bar "
        "helps, but not beyond chance."
    ),
}
"""Each figure's caption in the report: what it shows and what to look for."""


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, folder: Path, name: str) -> str:
    fig.tight_layout()
    fig.savefig(folder / name, dpi=DPI)
    _plt().close(fig)
    return name


def whole_log_excess(wb, fit) -> tuple[np.ndarray, np.ndarray]:
    """Window starts over the whole log and each window's whitened MSE above its noise
    floor (training and held-out blocks)."""
    data = wb.data
    starts = window_starts(data, wb.h_eval, wb.h_eval // wb.window_group or 1, "all", 1)
    if starts.size == 0:
        return starts, np.zeros(0)
    err, floor, _ = noise_rollouts(fit.model, fit.theta, data, starts, wb.h_eval)
    idx = list(FIT_STATES)
    mse = np.mean((err[:, :, idx] / data.sigma[idx]) ** 2, axis=(1, 2))
    return starts, mse - floor


def selection_path(report: dict, folder: Path) -> str:
    plt = _plt()
    base = report["baseline"]
    labels = ["baseline" if not report["selection"]["start"] else "start"]
    errors = [report["selection_errors"][0]]
    for step in report["selection"]["path"]:
        sign = "+" if step["action"] == "add" else "-"
        labels.append(f"{sign} {step['name']}")
        errors.append(step["heldout_error"])
    fig, ax = plt.subplots(figsize=(7, 3.4))
    ax.plot(range(len(errors)), errors, "o-", color="C3", label="held-out model error")
    ax.axhline(base["noise_floor"], color="0.4", ls="--", label="noise floor")
    ax.set_xticks(range(len(errors)), labels, rotation=15, fontsize=8)
    ax.set_ylabel("error (whitened RMS)")
    ax.set_title("the loop: error per step", fontsize=9)
    ax.legend(fontsize=8)
    return _save(fig, folder, "selection_path.png")


def error_over_log(wb, before, after, label_after: str, folder: Path) -> str:
    plt = _plt()
    data = wb.data
    fig, ax = plt.subplots(figsize=(10, 3.2))
    if after is None:  # the final model is the baseline: drawn dashed on top of it
        after, label_after = before, "final model (= baseline: no effect added)"
    for fit, color, label in ((before, "C0", "baseline"), (after, "C3", label_after)):
        starts, excess = whole_log_excess(wb, fit)
        t = data.t[starts + wb.h_eval // 2]
        ls = "--" if fit is before and color == "C3" else "-"
        ax.plot(t, np.sqrt(np.maximum(excess, 0.0)), color=color, lw=0.9, ls=ls, label=label)
    # contexts shaded, held-out blocks hatched
    ctx = data.context
    change = np.flatnonzero(np.diff(ctx)) + 1
    edges = np.concatenate([[0], change, [data.n - 1]])
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        ax.axvspan(data.t[a], data.t[b], color=f"C{2 + ctx[a] % 6}", alpha=0.12, lw=0)
        if len(data.context_names) > 1:
            ax.text(data.t[a], ax.get_ylim()[1] * 0.95, data.context_names[ctx[a]], fontsize=7)
    blocks = block_ids(data.n, wb.config.n_blocks)
    for b in heldout_blocks(wb.config.n_blocks):
        idx = np.flatnonzero(blocks == b)
        if idx.size:
            ax.axvspan(data.t[idx[0]], data.t[idx[-1]], fill=False, hatch="//", ec="0.7", lw=0)
    ax.set_xlabel("t [s] (hatched: held-out blocks; shading: contexts)")
    ax.set_ylabel("model error (above noise)")
    ax.set_title("error over the whole log", fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    return _save(fig, folder, "error_over_log.png")


def error_map(wb, before, after, label: str, folder: Path) -> str:
    """Two course maps on one colour scale: where ``before`` (the baseline) failed and what
    remains with ``after`` (the final model, ``label``)."""
    plt = _plt()
    data = wb.data
    panels = []
    for fit in (before, after):
        starts, excess = whole_log_excess(wb, fit)
        panels.append((starts + wb.h_eval // 2, np.sqrt(np.maximum(excess, 0.0))))
    top = max((float(np.max(e)) for _, e in panels if e.size), default=1.0) or 1.0
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    titles = ("baseline: where it failed", f"final model ({label}): what remains")
    for ax, (mid, err), title in zip(axes, panels, titles, strict=True):
        ax.plot(data.x[:, 0], data.x[:, 1], color="0.85", lw=0.6)
        sc = ax.scatter(
            data.x[mid, 0], data.x[mid, 1], c=err, s=9, cmap="inferno_r", vmin=0.0, vmax=top
        )
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("sx [m]")
        ax.set_title(title, fontsize=9)
    axes[0].set_ylabel("sy [m]")
    fig.colorbar(sc, ax=list(axes), label="model error (above noise)")
    fig.savefig(folder / "error_map.png", dpi=DPI)
    plt.close(fig)
    return "error_map.png"


def bias_plot(report: dict, folder: Path) -> str:
    """Per-state and per-context residual bias (0.2 s predictions) with 99 % intervals."""
    plt = _plt()
    resid = report["verdict"]["residual_structure"]
    rows = [t for t in resid["tests"] if t["kind"] == "autocorrelation"]
    per_ctx = report["verdict"].get("context_bias", {})
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4))
    ax = axes[0]
    for k, r in enumerate(rows):
        sig = report["noise_sigma"][r["state"]]
        ax.errorbar(k, r["bias"] / sig, yerr=2.576 * r["bias_se"] / sig, fmt="o", color="C3")
    ax.axhline(0, color="0.5", lw=0.8)
    ax.set_xticks(range(len(rows)), [r["state"] for r in rows])
    ax.set_ylabel("bias / noise scale")
    ax.set_title("final model: residual bias per state (99 % intervals)", fontsize=9)
    ax = axes[1]
    states = [r["state"] for r in rows]
    width = 0.8 / max(len(per_ctx), 1)
    for c, (name, biases) in enumerate(per_ctx.items()):
        xs = np.arange(len(states)) + (c - (len(per_ctx) - 1) / 2) * width
        ax.errorbar(
            xs,
            [biases[s]["bias"] for s in states],
            yerr=[2.576 * biases[s]["se"] for s in states],
            fmt="o",
            label=name,
        )
    ax.axhline(0, color="0.5", lw=0.8)
    ax.set_xticks(range(len(states)), states)
    ax.set_ylabel("bias / noise scale")
    ax.set_title("per context", fontsize=9)
    if per_ctx:
        ax.legend(fontsize=7)
    return _save(fig, folder, "bias.png")


def regimes_plot(wb, evals: list[tuple[str, dict]], folder: Path) -> str:
    plt = _plt()
    keys = ("speed", "lateral_accel", "steering_rate", "accel_command", "drive_mode")
    fig, axes = plt.subplots(1, len(keys), figsize=(16, 3.4))
    width = 0.8 / max(len(evals), 1)
    for k, (label, ev) in enumerate(evals):
        where = localise(ev, wb.eval_starts, wb.data, wb.window_group)
        for ax, key in zip(axes, keys, strict=True):
            rows = where["bins"].get(key, [])
            xs = np.arange(len(rows)) + (k - (len(evals) - 1) / 2) * width
            ax.bar(
                xs,
                [r["excess"] for r in rows],
                width,
                yerr=[2.576 * r["se"] for r in rows],
                label=label,
                color=f"C{0 if k == 0 else 3}",
            )
            ax.set_xticks(np.arange(len(rows)), [r["bin"] for r in rows], rotation=25, fontsize=7)
            ax.set_title(f"excess error by {key.replace('_', ' ')}", fontsize=9)
    axes[0].set_ylabel("whitened MSE above the noise floor")
    axes[0].legend(fontsize=7)
    return _save(fig, folder, "regimes.png")


def cross_correlation_plot(report: dict, folder: Path) -> str:
    plt = _plt()
    resid = report["verdict"]["residual_structure"]
    tests = [t for t in resid["tests"] if t["kind"].startswith("cross_correlation")]
    fig, axes = plt.subplots(1, len(INPUT_NAMES), figsize=(11, 3.4), squeeze=False)
    for ax, u in zip(axes[0], INPUT_NAMES, strict=True):
        band = 0.0
        for t in tests:
            if t["input"] != u:
                continue
            ax.plot(t["cross_corr"], lw=1, label=t["state"])
            band = max(band, t["band_99"])
        ax.axhspan(-band, band, color="0.88")
        ax.set_xlabel(f"lag [steps of {resid['step_s']:g} s] ({u} leading)")
        ax.set_title(f"final model: residual vs input {u}", fontsize=9)
        ax.legend(fontsize=7)
    return _save(fig, folder, "cross_correlation.png")


def overlay(wb, after_eval, label_after: str, folder: Path) -> str:
    """Measured, baseline and final model (``after_eval``, labelled ``label_after``; dashed
    when it is the baseline itself) over the held-out blocks' free runs."""
    plt = _plt()
    data = wb.data
    same = after_eval is wb.baseline_eval
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for ax, state in zip(axes, ("v", "psi_dot", "beta"), strict=True):
        i = STATE_NAMES.index(state)
        for k, (idx, sim) in enumerate(wb.baseline_eval["_free_run"]):
            ax.plot(data.t[idx], data.x[idx, i], "k", lw=0.8, label="measured" if k == 0 else None)
            ax.plot(data.t[idx], sim[:, i], "C0", lw=0.8, label="baseline" if k == 0 else None)
        for k, (idx, sim) in enumerate(after_eval.get("_free_run", [])):
            ax.plot(
                data.t[idx],
                sim[:, i],
                "C3",
                lw=0.8,
                ls="--" if same else "-",
                label=label_after if k == 0 else None,
            )
        ax.set_ylabel(state)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t [s] (held-out blocks, free run)")
    return _save(fig, folder, "overlay.png")


def ranking_plot(report: dict, folder: Path) -> str:
    plt = _plt()
    ranked = report["ranked_effects"]
    fig, ax = plt.subplots(figsize=(7, 0.3 * len(ranked) + 1.2))
    drops = [max(r["heldout_error_drop"], -0.1) for r in ranked]
    colors = ["C2" if r["significant"] else "0.6" for r in ranked]
    ax.barh([r["name"] for r in ranked][::-1], drops[::-1], color=colors[::-1])
    ax.set_xlabel("first round: held-out model error drop (green: significant)")
    return _save(fig, folder, "ranking.png")


def autocorr_plot(report: dict, folder: Path) -> str:
    plt = _plt()
    sets = [("baseline", report["baseline"]["residuals"]["whiteness"])]
    final = report.get("final", {}).get("residuals", {}).get("whiteness")
    if final is not None:
        sets.append(("final: " + (" + ".join(report["final"]["effects"]) or "baseline"), final))
    fig, axes = plt.subplots(1, len(sets), figsize=(6 * len(sets), 3.5), squeeze=False)
    for ax, (title, w) in zip(axes[0], sets, strict=True):
        band = 0.0
        for name, st in w["states"].items():
            ax.plot(range(1, len(st["autocorr"]) + 1), st["autocorr"], lw=1, label=name)
            band = max(band, st.get("band_99_lag2", w["band_99"]))
        ax.axhspan(-band, band, color="0.85")
        ax.set_title(f"one-step residual autocorrelation: {title}", fontsize=9)
        ax.set_xlabel("lag [samples]")
        ax.legend(fontsize=7)
    return _save(fig, folder, "residual_autocorr.png")


def all_figures(report: dict, wb, folder: Path) -> list[str]:
    """Every PNG of the report; returns their names in the order the page shows them."""
    final = getattr(wb, "final_fit", None)
    final_eval = getattr(wb, "final_eval", None)
    label = "+ " + " + ".join(final.model.effect_names) if final and final.model.effects else ""
    has_after = bool(label)
    if has_after and not final_eval.get("_free_run"):  # the loop evaluates without free runs
        final_eval = wb.evaluate(final)
    names = [selection_path(report, folder)]
    names.append(error_over_log(wb, wb.baseline, final if has_after else None, label, folder))
    names.append(error_map(wb, wb.baseline, final or wb.baseline, label or "= baseline", folder))
    evals = [("baseline", wb.baseline_eval)]
    if has_after:
        evals.append((label, final_eval))
    names.append(regimes_plot(wb, evals, folder))
    names.append(bias_plot(report, folder))
    names.append(cross_correlation_plot(report, folder))
    names.append(
        overlay(
            wb,
            final_eval if has_after else wb.baseline_eval,
            f"final model ({label})" if has_after else "final model (= baseline: no effect added)",
            folder,
        )
    )
    names.append(autocorr_plot(report, folder))
    names.append(ranking_plot(report, folder))
    return names
