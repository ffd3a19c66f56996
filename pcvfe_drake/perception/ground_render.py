"""Render the textured ground of a :class:`TerrainMap` through any affine pixel-to-world map.

Shared by the downward camera (a small rotated view under the car) and the top-down map image
(:func:`render_topdown`).
Each terrain's texture is tiled over the world (``tile_m`` metres per tile, north up) and sampled
with ``cv2.warpAffine`` (``BORDER_WRAP``); where several terrains are visible they are blended
by the largest of the bilinearly interpolated one-hot label masks, so region boundaries show as
sharp, smooth edges (no raster stairs). Cells with no terrain render black.
"""

from __future__ import annotations

import cv2
import numpy as np

from pcvfe_drake.perception.terrain import UNKNOWN, TerrainMap
from pcvfe_drake.perception.texture_library import TextureSet, default_textures


def _compose(outer: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """2x3 affine ``outer o inner``."""
    a = np.vstack([outer, [0.0, 0.0, 1.0]])
    b = np.vstack([inner, [0.0, 0.0, 1.0]])
    return (a @ b)[:2]


class GroundRenderer:
    """Renders RGB uint8 ground images of ``terrain_map`` with ``textures`` (default: packaged)."""

    def __init__(self, terrain_map: TerrainMap, textures: TextureSet | None = None) -> None:
        self.map = terrain_map
        if textures is None:
            textures = terrain_map.textures
        self.textures = textures if textures is not None else default_textures()
        for t in terrain_map.terrains:
            self.textures.entry(t.texture)  # fail early on unknown texture names
        self._levels: dict[tuple[str, int], np.ndarray] = {}
        m = terrain_map
        # world (x, y) -> raster coordinates with cell centres at integers
        self._world_to_raster = np.array(
            [
                [1.0 / m.resolution_m, 0.0, -m.x_min_m / m.resolution_m - 0.5],
                [0.0, -1.0 / m.resolution_m, m.y_max_m / m.resolution_m - 0.5],
            ]
        )
        self._flat_colors = np.zeros((256, 3), dtype=np.float32)
        for k, t in enumerate(terrain_map.terrains):
            self._flat_colors[k] = self.textures.mean_rgb(t.texture)

    # ------------------------------------------------------------------------- textures
    def _texture_level(self, name: str, src_px_per_dst_px: float) -> tuple[np.ndarray, float, int]:
        """Texture pre-shrunk by a power of two so one output pixel covers about one texel
        (avoids aliasing when zoomed out). Returns (image, shrink factor, level)."""
        level = 0
        while src_px_per_dst_px / (2 ** (level + 1)) >= 1.0 and level < 8:
            level += 1
        key = (name, level)
        if key not in self._levels:
            image = self.textures.image(name)
            if level:
                h, w = image.shape[:2]
                size = (max(1, w >> level), max(1, h >> level))
                image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
            self._levels[key] = image
        image = self._levels[key]
        return image, self.textures.image(name).shape[1] / image.shape[1], level

    def _tiled(self, name: str, image: np.ndarray, level: int, reps: int) -> np.ndarray:
        key = (f"{name}@tiled{reps}", level)
        if key not in self._levels:
            self._levels[key] = np.ascontiguousarray(np.tile(image, (reps, reps, 1)))
        return self._levels[key]

    def _sample_texture(
        self, name: str, px_to_world: np.ndarray, shape: tuple[int, int]
    ) -> np.ndarray:
        base_w = self.textures.image(name).shape[1]
        texel_per_m = base_w / self.textures.tile_m(name)
        m_per_px = float(np.sqrt(abs(np.linalg.det(px_to_world[:, :2]))))
        image, shrink, level = self._texture_level(name, m_per_px * texel_per_m)
        h, w = image.shape[:2]
        s = texel_per_m / shrink
        world_to_tex = np.array([[s, 0.0, 0.0], [0.0, -s, 0.0]])
        a = _compose(world_to_tex, px_to_world)
        # Texel footprint of the view; shift it (by whole tiles) to start inside the first tile.
        hh, ww = shape
        corners = np.array([[0, 0, 1], [ww, 0, 1], [0, hh, 1], [ww, hh, 1]], float) @ a.T
        lo = corners.min(axis=0) - 2.0
        hi = corners.max(axis=0) + 2.0
        a[0, 2] -= np.floor(lo[0] / w) * w
        a[1, 2] -= np.floor(lo[1] / h) * h
        reps = int(np.ceil((w + hi[0] - lo[0]) / w)), int(np.ceil((h + hi[1] - lo[1]) / h))
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        if max(reps) <= 4:
            # A pre-tiled canvas (2x2 or 4x4 tiles) holds the whole view: no per-pixel wrapping.
            canvas = self._tiled(name, image, level, 2 if max(reps) <= 2 else 4)
            return cv2.warpAffine(canvas, a, (ww, hh), flags=flags, borderMode=cv2.BORDER_REPLICATE)
        return cv2.warpAffine(image, a, (ww, hh), flags=flags, borderMode=cv2.BORDER_WRAP)

    # ------------------------------------------------------------------------- labels
    def visible_labels(
        self, px_to_world: np.ndarray, shape: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Labels under the view: (sorted unique labels incl. UNKNOWN if any, label crop, 2x3
        affine from output pixels to crop coordinates). The crop is the raster window (one cell
        margin) holding the whole view; cells beyond the map are UNKNOWN, or the map's
        ``outside`` terrain."""
        h, w = shape
        corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], float)
        px_to_raster = _compose(self._world_to_raster, px_to_world)
        cr = corners @ px_to_raster.T  # (4, 2) raster (col, row)
        c0 = int(np.floor(cr[:, 0].min())) - 1
        c1 = int(np.ceil(cr[:, 0].max())) + 2
        r0 = int(np.floor(cr[:, 1].min())) - 1
        r1 = int(np.ceil(cr[:, 1].max())) + 2
        rows, cols = self.map.labels.shape
        fill = UNKNOWN if self.map.outside is None else self.map.index_of(self.map.outside)
        if r0 >= 0 and c0 >= 0 and r1 <= rows and c1 <= cols:
            crop = self.map.labels[r0:r1, c0:c1]
        else:
            crop = np.full((r1 - r0, c1 - c0), fill, dtype=np.uint8)
            rr0, rr1 = max(r0, 0), min(r1, rows)
            cc0, cc1 = max(c0, 0), min(c1, cols)
            if rr1 > rr0 and cc1 > cc0:
                crop[rr0 - r0 : rr1 - r0, cc0 - c0 : cc1 - c0] = self.map.labels[rr0:rr1, cc0:cc1]
        if self.map.outside is not None:
            crop = np.where(crop == UNKNOWN, np.uint8(fill), crop)
        present = np.flatnonzero(np.bincount(crop.ravel(), minlength=256))
        px_to_crop = px_to_raster.copy()
        px_to_crop[0, 2] -= c0
        px_to_crop[1, 2] -= r0
        return present, crop, px_to_crop

    # ------------------------------------------------------------------------- render
    def render(
        self, px_to_world: np.ndarray, shape: tuple[int, int], *, flat: bool = False
    ) -> np.ndarray:
        """RGB uint8 image of ``shape = (H, W)`` whose pixel (col c, row r) shows world point
        ``px_to_world @ [c, r, 1]`` (2x3 affine, metres)."""
        px_to_world = np.asarray(px_to_world, dtype=float)
        if px_to_world.shape != (2, 3) or not np.all(np.isfinite(px_to_world)):
            raise ValueError(f"px_to_world must be a finite 2x3 affine, got {px_to_world!r}")
        present, crop, px_to_crop = self.visible_labels(px_to_world, shape)
        h, w = shape

        def layer(k: int, x0: int = 0, y0: int = 0, ww: int = w, hh: int = h) -> np.ndarray:
            """Terrain k drawn on the sub-rectangle (x0, y0, ww, hh) of the output."""
            if k == UNKNOWN:
                return np.zeros((hh, ww, 3), np.uint8)
            if flat:
                return np.full((hh, ww, 3), self._flat_colors[k].astype(np.uint8))
            sub = px_to_world.copy()
            sub[:, 2] += px_to_world[:, :2] @ [x0, y0]
            return self._sample_texture(self.map.terrains[k].texture, sub, (hh, ww))

        if present.size == 1:
            return np.ascontiguousarray(layer(int(present[0])))
        # Several terrains: each pixel shows the terrain whose one-hot label mask, interpolated
        # bilinearly, is largest there (a smooth boundary instead of the raster's stairs). The
        # masks are evaluated every `step` pixels and upsampled: the raster is far coarser.
        step = 4 if (h % 4 == 0 and w % 4 == 0 and min(h, w) >= 32) else 1
        low = _compose(px_to_crop, np.array([[step, 0, (step - 1) / 2], [0, step, (step - 1) / 2]]))
        winner = np.zeros((h, w), np.uint8)
        best = None
        for i, k in enumerate(present):
            m = cv2.warpAffine(
                (crop == k).astype(np.float32),
                low,
                (w // step, h // step),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE,
            )
            if step > 1:
                m = cv2.resize(m, (w, h), interpolation=cv2.INTER_LINEAR)
            if best is None:
                best = m
            else:
                winner[m > best] = i
                best = np.maximum(best, m)
        out = np.empty((h, w, 3), np.uint8)
        for i, k in enumerate(present):
            mask = (winner == i).view(np.uint8)
            x0, y0, ww, hh = cv2.boundingRect(mask)
            if ww == 0 or hh == 0:
                continue
            cv2.copyTo(
                layer(int(k), x0, y0, ww, hh),
                mask[y0 : y0 + hh, x0 : x0 + ww],
                out[y0 : y0 + hh, x0 : x0 + ww],
            )
        return out


def render_topdown(
    terrain_map: TerrainMap, px_per_m: float = 4.0, *, flat: bool = False, textures=None
) -> np.ndarray:
    """Top-down RGB image (H, W, 3) uint8 of the whole map, north up, ``px_per_m`` pixels per
    metre. ``flat=True`` paints each terrain in its texture's mean colour instead of the
    tiled texture. ``textures``: a ``TextureSet`` (default: the packaged textures)."""
    m = terrain_map
    if not (np.isfinite(px_per_m) and px_per_m > 0):
        raise ValueError(f"px_per_m must be positive, got {px_per_m!r}")
    width = int(round((m.x_max_m - m.x_min_m) * px_per_m))
    height = int(round((m.y_max_m - m.y_min_m) * px_per_m))
    if width * height > 40_000_000:
        raise ValueError(f"px_per_m={px_per_m} gives a {width}x{height} image; use fewer")
    renderer = GroundRenderer(m, textures)
    m_per_px = 1.0 / px_per_m
    # pixel (c, r) -> world: x = x_min + (c + 0.5) / ppm, y = y_max - (r + 0.5) / ppm
    px_to_world = np.array(
        [
            [m_per_px, 0.0, m.x_min_m + 0.5 * m_per_px],
            [0.0, -m_per_px, m.y_max_m - 0.5 * m_per_px],
        ]
    )
    return renderer.render(px_to_world, (height, width), flat=flat)
