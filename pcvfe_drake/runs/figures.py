"""The paper's figures from a run log (matplotlib, Agg backend; no pydrake).

- :func:`figure_contexts_map` (paper Fig. 4): the driven path on the terrain map, each logged
  position a dot in the colour of the context reported there (noise black), with example camera
  frames of every context beside it.
- :func:`figure_mu_over_time` (Fig. 5): friction estimate (orange) vs truth (blue) over time,
  the background shaded by the detected context.
- :func:`figure_reidentification` (Fig. 7): a zoom on one re-identification: entry into the known
  terrain, the moment its id is reported, and the latency between them.

Inputs are the run log columns described in ``pcvfe_drake.runs.summary`` plus the summary dict.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from pcvfe_drake.runs.palette import context_rgb  # noqa: E402

ESTIMATE_COLOR = "tab:orange"
TRUTH_COLOR = "tab:blue"


def context_runs(t_s: np.ndarray, context: np.ndarray) -> list[tuple[float, float, int]]:
    """Maximal runs of one context id: (t_start, t_end, id); t_end is the next run's start."""
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(context, dtype=int)
    if t.size == 0:
        return []
    change = np.flatnonzero(np.diff(c) != 0) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [t.size]])
    dt_last = t[-1] - t[-2] if t.size > 1 else 0.0
    out = []
    for a, b in zip(starts, ends, strict=True):
        t_end = t[b] if b < t.size else t[-1] + dt_last
        out.append((float(t[a]), float(t_end), int(c[a])))
    return out


def _shade_contexts(ax, t_s: np.ndarray, context: np.ndarray, alpha: float = 0.22) -> None:
    for t0, t1, k in context_runs(t_s, context):
        ax.axvspan(t0, t1, color=context_rgb(k), alpha=alpha if k >= 0 else 0.12, lw=0)


def _context_legend(ids: list[int], names: Mapping[int, str]) -> list[Patch]:
    handles = []
    for k in ids:
        label = "noise" if k < 0 else f"context {k}" + (f" ({names[k]})" if names.get(k) else "")
        handles.append(Patch(color=context_rgb(k), label=label))
    return handles


def _majority_names(summary: Mapping[str, Any] | None) -> dict[int, str]:
    if not summary:
        return {}
    return {int(e["id"]): e.get("majority_terrain") or "" for e in summary.get("mu_estimates", [])}


def _example_frames(
    log: pd.DataFrame, log_dir: Path | None, per_context: int, column: str
) -> dict[int, list[np.ndarray]]:
    """Up to ``per_context`` logged camera frames per context id (in ``column``), spread over
    its rows."""
    if "image" not in log.columns or log_dir is None:
        return {}
    import cv2

    frames: dict[int, list[np.ndarray]] = {}
    has_image = log["image"].fillna("").astype(str).str.len() > 0
    for k in sorted(int(c) for c in log[column].unique()):
        rows = log.index[has_image & (log[column] == k)]
        if len(rows) == 0:
            continue
        pick = rows[np.linspace(0, len(rows) - 1, min(per_context, len(rows))).round().astype(int)]
        images = []
        for r in pick:
            path = Path(str(log.at[r, "image"]))
            path = path if path.is_absolute() else log_dir / path
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if bgr is not None:
                images.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        if images:
            frames[k] = images
    return frames


def _draw_map(ax, log, column, title, map_image, map_bounds_m, reference_xy, names) -> None:
    if map_image is not None and map_bounds_m is not None:
        x0, x1, y0, y1 = map_bounds_m
        ax.imshow(map_image, extent=(x0, x1, y0, y1), origin="upper", alpha=0.55)
    xs = [log["sx"].to_numpy(float)]
    ys = [log["sy"].to_numpy(float)]
    if reference_xy is not None:
        ref = np.asarray(reference_xy)
        ax.plot(
            np.append(ref[:, 0], ref[0, 0]),
            np.append(ref[:, 1], ref[0, 1]),
            color="white",
            lw=1.0,
            ls="--",
        )
        xs.append(ref[:, 0])
        ys.append(ref[:, 1])
    ids = log[column].to_numpy(int)
    ax.scatter(log["sx"], log["sy"], c=[context_rgb(k) for k in ids], s=6, lw=0)
    xs, ys = np.concatenate(xs), np.concatenate(ys)
    pad = 8.0
    ax.set_xlim(np.nanmin(xs) - pad, np.nanmax(xs) + pad)
    ax.set_ylim(np.nanmin(ys) - pad, np.nanmax(ys) + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)
    present = sorted(set(ids.tolist()))
    ax.legend(handles=_context_legend(present, names), loc="upper right", fontsize=7)


def figure_contexts_map(
    log: pd.DataFrame,
    path: str | Path,
    *,
    map_image: np.ndarray | None = None,
    map_bounds_m: tuple[float, float, float, float] | None = None,
    reference_xy: np.ndarray | None = None,
    summary: Mapping[str, Any] | None = None,
    log_dir: str | Path | None = None,
    frames_per_context: int = 3,
) -> Path:
    """Paper Fig. 4: discovered contexts on the map (dots: position and context; black: noise),
    with example frames per context. With a ``final_context`` column the left map shows every
    frame labelled by the final clustering (the paper's figure) and a second map the ids as
    reported online during the run; frames are grouped by the left map's labels."""
    path = Path(path)
    has_final = "final_context" in log.columns
    column = "final_context" if has_final else "context"
    frames = _example_frames(log, Path(log_dir) if log_dir else None, frames_per_context, column)
    names = _majority_names(summary)
    n_maps = 2 if has_final else 1
    n_rows = max(1, len(frames))
    fig = plt.figure(
        figsize=(6.5 * n_maps + 1.3 * frames_per_context, max(5.5, 1.5 * n_rows)),
        constrained_layout=True,
    )
    grid = fig.add_gridspec(
        n_rows, n_maps + frames_per_context, width_ratios=[5] * n_maps + [1] * frames_per_context
    )
    maps = [
        (column, "Discovered contexts, final clustering" if has_final else "Discovered contexts")
    ]
    if has_final:
        maps.append(("context", "Context ids as reported online during the run"))
    for i, (col, title) in enumerate(maps):
        ax = fig.add_subplot(grid[:, i])
        _draw_map(ax, log, col, title, map_image, map_bounds_m, reference_xy, names)
    for row, (k, images) in enumerate(sorted(frames.items())):
        for col in range(frames_per_context):
            sub = fig.add_subplot(grid[row, n_maps + col])
            sub.set_xticks([])
            sub.set_yticks([])
            if col >= len(images):
                sub.axis("off")
                continue
            sub.imshow(images[col])
            for spine in sub.spines.values():
                spine.set_edgecolor(context_rgb(k))
                spine.set_linewidth(3)
            if col == 0:
                label = "noise" if k < 0 else f"ctx {k}"
                if names.get(k):
                    label += f"\n{names[k]}"
                sub.set_ylabel(label, fontsize=8)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _plot_mu(ax, log: pd.DataFrame) -> None:
    """Estimate and truth over time on ``ax``, the background shaded by the reported context."""
    t = log["t"].to_numpy(float)
    _shade_contexts(ax, t, log["context"].to_numpy(int))
    ax.step(t, log["mu_true"], where="post", color=TRUTH_COLOR, lw=1.8, label="true mu")
    ax.step(t, log["mu_hat"], where="post", color=ESTIMATE_COLOR, lw=1.8, label="PC-VFE estimate")
    ax.set_ylabel("friction coefficient mu [-]")
    ax.set_xlim(t[0], t[-1])
    top = np.nanmax(np.concatenate([log["mu_true"], log["mu_hat"]]))
    ax.set_ylim(0.0, max(1.0, 1.1 * top))


def _plot_lower_bounds(ax, log: pd.DataFrame, summary: Mapping[str, Any] | None) -> None:
    """Each context's used-friction lower bound (final table) as a dotted line over the time it
    was reported, marked where the data never came near the limit (mu not identifiable)."""
    t = log["t"].to_numpy(float)
    ctx = log["context"].to_numpy(int)
    labelled = False
    for e in (summary or {}).get("mu_estimates", []):
        bound = e.get("mu_lower_bound")
        rows = ctx == int(e["id"])
        if bound is None or not np.isfinite(bound) or not rows.any():
            continue
        t0, t1 = float(t[rows].min()), float(t[rows].max())
        ax.hlines(
            bound,
            t0,
            t1,
            colors=ESTIMATE_COLOR,
            linestyles=":",
            lw=1.4,
            label=None if labelled else "friction used (lower bound on mu)",
        )
        labelled = True
        if e.get("near_limit") is False:
            ax.text(t0, bound, " never near the limit", fontsize=7, va="bottom")


def _plot_intervals(ax, log: pd.DataFrame, summary: Mapping[str, Any] | None) -> None:
    """Each context's final 95 % interval of mu (the summary's ``interval_95``) as a band over
    the time the context was reported; a one-sided interval (data never near the limit) is
    drawn from its lower bound to the top of the axes."""
    t = log["t"].to_numpy(float)
    ctx = log["context"].to_numpy(int)
    labelled = False
    top = ax.get_ylim()[1]
    for e in (summary or {}).get("mu_estimates", []):
        interval = e.get("interval_95")
        rows = ctx == int(e["id"])
        if not interval or interval[0] is None or not rows.any():
            continue
        lo, hi = float(interval[0]), top if interval[1] is None else float(interval[1])
        t0, t1 = float(t[rows].min()), float(t[rows].max())
        ax.fill_between(
            [t0, t1],
            [lo, lo],
            [hi, hi],
            color=ESTIMATE_COLOR,
            alpha=0.12,
            lw=0,
            label=None if labelled else "final estimate's 95 % interval",
        )
        labelled = True


def figure_mu_over_time(
    log: pd.DataFrame, path: str | Path, *, summary: Mapping[str, Any] | None = None
) -> Path:
    """Paper Fig. 5: friction estimate vs truth over time, shaded by the detected context."""
    path = Path(path)
    fig, ax = plt.subplots(figsize=(11, 4), constrained_layout=True)
    _plot_mu(ax, log)
    _plot_intervals(ax, log, summary)
    _plot_lower_bounds(ax, log, summary)
    ax.set_xlabel("time [s]")
    ids = sorted(set(log["context"].astype(int).tolist()))
    handles = ax.get_legend_handles_labels()[0] + _context_legend(ids, _majority_names(summary))
    ax.legend(handles=handles, loc="upper left", fontsize=8, ncol=2)
    ax.set_title("Friction estimate vs truth; background: detected context")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def figure_reidentification(
    log: pd.DataFrame,
    path: str | Path,
    *,
    summary: Mapping[str, Any],
    window_s: float = 6.0,
) -> Path | None:
    """Paper Fig. 7: zoom on the re-identification with the longest finite latency (None if the
    run has none)."""
    entries = [
        e for e in summary.get("reidentification_latency_s", []) if e["latency_s"] is not None
    ]
    if not entries:
        return None
    e = max(entries, key=lambda entry: entry["latency_s"])
    path = Path(path)
    t_enter = float(e["t_enter_s"])
    t_id = t_enter + float(e["latency_s"])
    t = log["t"].to_numpy(float)
    sel = (t >= t_enter - window_s) & (t <= t_id + window_s)
    part = log[sel]
    tt = part["t"].to_numpy(float)
    fig, (ax_mu, ax_id) = plt.subplots(
        2, 1, figsize=(9, 5), sharex=True, height_ratios=[3, 1], constrained_layout=True
    )
    _plot_mu(ax_mu, part)
    for ax in (ax_mu, ax_id):
        ax.axvline(t_enter, color="k", ls="--", lw=1)
        ax.axvline(t_id, color="k", ls="-", lw=1)
    ax_mu.annotate(
        f"latency {e['latency_s']:.2f} s",
        xy=(t_id, 0.05),
        xytext=(t_id + 0.3, 0.12),
        fontsize=10,
        arrowprops={"arrowstyle": "->"},
    )
    ax_mu.legend(loc="upper left", fontsize=8)
    ax_mu.set_title(
        f"Re-identification of {e['terrain']}: entered at {t_enter:.1f} s (dashed), id reported "
        f"at {t_id:.1f} s (solid)\nthe longest of {len(entries)} re-identification(s) in the run",
        fontsize=10,
    )
    ax_id.step(tt, part["context"], where="post", color="k")
    ax_id.set_ylabel("context id")
    ax_id.set_xlabel("time [s]")
    ax_id.set_xlim(tt[0], tt[-1])
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_figures(
    log: pd.DataFrame,
    folder: str | Path,
    summary: Mapping[str, Any],
    *,
    map_image: np.ndarray | None = None,
    map_bounds_m: tuple[float, float, float, float] | None = None,
    reference_xy: np.ndarray | None = None,
    log_dir: str | Path | None = None,
) -> dict[str, str | None]:
    """All three figures into ``folder``; returns {figure name: path or None (not drawable)}."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fig4 = figure_contexts_map(
        log,
        folder / "fig4_contexts_map.png",
        map_image=map_image,
        map_bounds_m=map_bounds_m,
        reference_xy=reference_xy,
        summary=summary,
        log_dir=log_dir,
    )
    fig5 = figure_mu_over_time(log, folder / "fig5_mu_over_time.png", summary=summary)
    fig7 = figure_reidentification(log, folder / "fig7_reidentification.png", summary=summary)
    return {
        "fig4_contexts_map": str(fig4),
        "fig5_mu_over_time": str(fig5),
        "fig7_reidentification": str(fig7) if fig7 else None,
    }
