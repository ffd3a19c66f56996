"""``pcvfe terrain-map``: render a world's terrain map top-down to a PNG and list its terrains."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from pcvfe_drake.perception.ground_render import render_topdown
from pcvfe_drake.runs.output_paths import OutputPathError, check_output_file, write_failed


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "terrain-map",
        help="render a world's terrain map top-down (PNG) and list its terrains",
        description=(
            "Render a world's terrain map (default: the paper's four quadrants with their "
            "transition strips) as a north-up RGB image, textures tiled at their world size, "
            "and print each terrain's friction and area."
        ),
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("terrain_map.png"),
        help="image file; the suffix picks the format (.png, .jpg, .bmp, .tif, ...)",
    )
    parser.add_argument("--px-per-m", type=float, default=4.0, help="resolution [px/m]")
    parser.add_argument(
        "--world",
        default="paper",
        help="shipped world (paper, paper_small, paper_no_strips) or world file (docs/worlds.md)",
    )
    parser.add_argument("--flat", action="store_true", help="mean colours instead of textures")
    parser.set_defaults(func=run)


def check_image_path(path: Path) -> Path:
    """``path`` if OpenCV can write an image there (its suffix names a known format)."""
    check_output_file(path)
    if not path.suffix or not cv2.haveImageWriter(str(path)):
        raise OutputPathError(
            f"--out {path}: unknown image format {path.suffix or '(no suffix)'!r}; "
            "use .png, .jpg, .bmp or .tif"
        )
    return path


def write_image(path: Path, rgb: np.ndarray) -> None:
    """Encode ``rgb`` in the format of ``path``'s suffix and write it (OS errors name the path)."""
    ok, encoded = cv2.imencode(path.suffix, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise OutputPathError(f"--out {path}: OpenCV could not encode the image as {path.suffix}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(encoded.tobytes())
    except OSError as exc:
        raise write_failed(exc, "--out", path) from exc


def run(args: argparse.Namespace) -> int:
    check_image_path(args.out)
    from pcvfe_drake.diagrams.world_io import world_terrain_map

    terrain = world_terrain_map(args.world)
    image = render_topdown(terrain, args.px_per_m, flat=args.flat)
    write_image(args.out, image)
    x0, x1, y0, y1 = terrain.bounds_m
    h, w = image.shape[:2]
    print(f"terrain map x in [{x0:g}, {x1:g}] m, y in [{y0:g}, {y1:g}] m, "
          f"{terrain.resolution_m:g} m cells -> {args.out} ({w}x{h})")  # fmt: skip
    counts = np.bincount(terrain.labels.ravel(), minlength=len(terrain.terrains))
    cell_area = terrain.resolution_m**2
    for k, t in enumerate(terrain.terrains):
        area = counts[k] * cell_area
        texture = Path(t.texture).name
        print(f"  {t.name:14s} mu {t.mu:4.2f}  texture {texture:14s} {area:8.0f} m^2")
    return 0
