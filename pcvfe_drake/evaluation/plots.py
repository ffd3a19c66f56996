"""Figures of the evaluation report (matplotlib, Agg; no pydrake).

- :func:`plot_bars`: mean speed and catastrophic failures per source, bars with 95 % intervals,
  one group per scenario.
- :func:`plot_mu_over_time`: mu_hat over time of every source on one seed (and the true mu).
- :func:`plot_failure_map`: where each failure happened, on the terrain map and the course.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from pcvfe_drake.evaluation.stats import mean_ci  # noqa: E402

_MARKERS = "ovs^DP*Xh<>p"


def source_colours(sources: list[str]) -> dict[str, tuple]:
    cmap = plt.get_cmap("tab10")
    return {s: cmap(i % 10) for i, s in enumerate(sources)}


def plot_bars(runs: pd.DataFrame, sources: list[str], path: Path) -> Path:
    """Bars of mean speed and failures per source (mean over seeds, 95 % CI whiskers)."""
    ok = runs[runs["status"] == "done"]
    scenarios = sorted(ok["scenario"].unique()) or ["-"]
    colours = source_colours(sources)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    width = 0.8 / max(len(sources), 1)
    for ax, (col, label) in zip(
        axes,
        (("mean_speed_mps", "mean speed [m/s]"), ("failures", "catastrophic failures per run")),
        strict=True,
    ):
        for j, src in enumerate(sources):
            means, errs = [], [[], []]
            for sc in scenarios:
                ci = mean_ci(ok[(ok["source"] == src) & (ok["scenario"] == sc)][col])
                means.append(ci.mean)
                lo = ci.mean - ci.lo if np.isfinite(ci.lo) else 0.0
                hi = ci.hi - ci.mean if np.isfinite(ci.hi) else 0.0
                errs[0].append(lo)
                errs[1].append(hi)
            x = np.arange(len(scenarios)) + (j - (len(sources) - 1) / 2) * width
            ax.bar(x, means, width, yerr=errs, capsize=3, color=colours[src], label=src)
        ax.set_xticks(np.arange(len(scenarios)), scenarios)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8, loc="lower right")
    fig.suptitle("mean over seeds, 95 % confidence interval")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_mu_over_time(
    logs: dict[str, pd.DataFrame], sources: list[str], title: str, path: Path
) -> Path:
    """mu_hat(t) of every source's drive log (one seed) over the true mu of the first log."""
    colours = source_colours(sources)
    fig, ax = plt.subplots(figsize=(11, 4.2))
    truth_drawn = False
    for src in sources:
        log = logs.get(src)
        if log is None or log.empty:
            continue
        if not truth_drawn:
            ax.plot(log["t"], log["mu_true"], color="k", lw=2.0, ls="--", label="true mu")
            truth_drawn = True
        ax.plot(log["t"], log["mu_hat"], color=colours[src], lw=1.2, label=src)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("mu given to the controller")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=4)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_failure_map(
    failures: pd.DataFrame,
    sources: list[str],
    maps: dict[str, tuple[np.ndarray | None, tuple, np.ndarray]],
    path: Path,
) -> Path:
    """Failure places per scenario: ``maps[scenario] = (image, (x0, x1, y0, y1), course_xy)``."""
    colours = source_colours(sources)
    scenarios = list(maps) or ["-"]
    fig, axes = plt.subplots(1, len(scenarios), figsize=(6.5 * len(scenarios), 6), squeeze=False)
    for ax, sc in zip(axes[0], scenarios, strict=True):
        if sc in maps:
            image, (x0, x1, y0, y1), course_xy = maps[sc]
            if image is not None:
                ax.imshow(image, extent=(x0, x1, y0, y1), origin="upper", alpha=0.5)
            ax.plot(course_xy[:, 0], course_xy[:, 1], color="k", lw=0.8, alpha=0.6)
        here = failures[failures["scenario"] == sc] if not failures.empty else failures
        n = 0
        for j, src in enumerate(sources):
            f = here[here["source"] == src] if not here.empty else here
            if f.empty:
                continue
            n += len(f)
            ax.scatter(
                f["sx_m"].astype(float),
                f["sy_m"].astype(float),
                s=50,
                marker=_MARKERS[j % len(_MARKERS)],
                color=colours[src],
                edgecolor="k",
                label=f"{src} ({len(f)})",
                zorder=3,
            )
        ax.set_title(f"{sc}: {n} failure(s)")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal")
        if n:
            ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
