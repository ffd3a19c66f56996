"""A world drawn from above: regions coloured by terrain with their mu, the course and its start
(matplotlib, Agg backend; no pydrake)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

MAX_IMAGE_PX = 1600
"""Longest side of the drawn terrain image [px] (the raster is shown downsampled)."""


def world_figure(terrain_map, course, title: str, path: Path) -> Path:
    """Draw ``terrain_map`` (``TerrainMap``) with ``course`` (``Course`` or None) to ``path``
    (PNG)."""
    labels = terrain_map.labels
    step = max(1, int(np.ceil(max(labels.shape) / MAX_IMAGE_PX)))
    small = labels[step // 2 :: step, step // 2 :: step]
    cmap = plt.get_cmap("tab20")
    colours = np.ones((256, 3))
    for k in range(len(terrain_map.terrains)):
        colours[k] = cmap(k % 20)[:3]
    image = colours[small]
    x0, x1, y0, y1 = terrain_map.bounds_m
    fig, ax = plt.subplots(figsize=(9, 9 * (y1 - y0) / (x1 - x0) + 0.6), dpi=120)
    ax.imshow(image, extent=(x0, x1, y0, y1), origin="upper", interpolation="nearest")
    if course is not None:
        ax.plot(course.x, course.y, color="k", lw=1.2, label=f"course {course.name}")
        ax.plot(course.x[0], course.y[0], "o", ms=9, mfc="w", mec="k", label="start (s = 0)")
        ahead = int(min(0.03 * course.length, 30.0) / course.ds)  # the direction of travel
        ax.annotate(
            "",
            xy=(course.x[ahead], course.y[ahead]),
            xytext=(course.x[0], course.y[0]),
            arrowprops={"arrowstyle": "->", "lw": 1.5},
        )
    rows, cols = np.indices(small.shape)
    xs = x0 + (cols + 0.5) * step * terrain_map.resolution_m
    ys = y1 - (rows + 0.5) * step * terrain_map.resolution_m
    handles = []
    for k, t in enumerate(terrain_map.terrains):
        mask = small == k
        if not mask.any():
            continue
        # Label the terrain at its cell nearest to the middle of its cells (inside the region).
        mx, my = xs[mask].mean(), ys[mask].mean()
        i = int(np.argmin((xs[mask] - mx) ** 2 + (ys[mask] - my) ** 2))
        variation = " ~" if terrain_map.mu_fields[k] is not None else ""
        ax.text(
            xs[mask][i],
            ys[mask][i],
            f"{t.name}\nmu {t.mu:.2f}{variation}",
            ha="center",
            va="center",
            fontsize=8,
            bbox={"fc": "w", "alpha": 0.7, "lw": 0},
        )
        handles.append(Patch(color=colours[k], label=f"{t.name} (mu {t.mu:.2f})"))
    ax.legend(
        handles=handles + ax.get_legend_handles_labels()[0],
        loc="upper right",
        fontsize=7,
        framealpha=0.85,
    )
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)
    ax.set_aspect("equal")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
