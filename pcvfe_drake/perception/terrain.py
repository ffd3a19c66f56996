"""Terrain map: which terrain (name, texture, true friction) lies under each world point.

World frame: x east, y north, metres (the same frame as the single-track state ``sx, sy``).

A :class:`TerrainMap` is a label raster over an axis-aligned world rectangle: cell ``(row, col)``
covers ``x in [x_min + col * res, x_min + (col + 1) * res)`` and
``y in (y_max - (row + 1) * res, y_max - row * res]``; row 0 is the northern edge, as in an image
file. Maps are built from polygons (rasterised at ``resolution_m``: a cell belongs to a region
when its centre does) or directly from a label image with its world placement. Every look-up
(the plant's friction, the camera's ground image, the top-down figure) reads the same raster, so
what the camera shows and the friction the car feels always agree.

Points outside the map (or on cells that no region covers) raise a ``ValueError`` naming the point,
unless the map was given an ``outside`` terrain, which is then used for them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

UNKNOWN = 255  # label of raster cells that no region covers


@dataclass(frozen=True)
class Terrain:
    """One terrain: ``name`` (unique in a map), true friction coefficient ``mu`` [-] and the name
    of its texture in ``textures/index.yaml``."""

    name: str
    mu: float
    texture: str

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Terrain name must be a non-empty string, got {self.name!r}")
        if not np.isfinite(self.mu) or not 0.0 < self.mu <= 2.0:
            raise ValueError(f"Terrain {self.name!r}: mu must be in (0, 2], got {self.mu!r}")
        if not isinstance(self.texture, str) or not self.texture:
            raise ValueError(f"Terrain {self.name!r}: texture must be a name, got {self.texture!r}")


MAX_RASTER_CELLS = 50_000_000
"""Most cells of a terrain raster (one byte each: 50 MB, a 350 m square at 5 cm): a larger
world or a finer resolution is refused before the raster is allocated."""


def raster_shape(
    bounds_m: tuple[float, float, float, float], resolution_m: float
) -> tuple[int, int]:
    """(rows, cols) of the raster of ``bounds_m = (x_min, x_max, y_min, y_max)`` at
    ``resolution_m`` metres per cell; a ValueError with the cells and memory it implies when
    that exceeds :data:`MAX_RASTER_CELLS`."""
    x_min, x_max, y_min, y_max = (float(b) for b in bounds_m)
    if not (np.isfinite(resolution_m) and resolution_m > 0):
        raise ValueError(f"resolution_m must be positive, got {resolution_m!r}")
    cols_f = round((x_max - x_min) / resolution_m)
    rows_f = round((y_max - y_min) / resolution_m)
    cells = float(cols_f) * float(rows_f)
    if cells > MAX_RASTER_CELLS:
        raise ValueError(
            f"resolution_m={resolution_m!r} over {x_max - x_min:g} m x {y_max - y_min:g} m is "
            f"{cells:.3g} cells (~{cells / 1e6:.3g} MB), more than {MAX_RASTER_CELLS:.3g}: "
            "use a coarser resolution or a smaller world"
        )
    return int(rows_f), int(cols_f)


class TerrainMap:
    """Label raster of terrains over a world rectangle, with vectorised look-ups.

    Args:
        labels: (H, W) integer label image; value k means ``terrains[k]``, 255 means no terrain.
            Row 0 is the northern (max y) edge.
        terrains: the terrains, indexed by label (at most 255).
        x_min_m, y_min_m: world coordinates of the south-west corner of the raster [m].
        resolution_m: side length of one cell [m].
        outside: name of a terrain used for points outside the raster or on uncovered cells;
            None (default) makes such look-ups raise ``ValueError``.
        mu_fields: per terrain (by label), an optional :class:`MuField` added to its mu where
            the terrain lies (None: uniform mu on every terrain).
        textures: the ``TextureSet`` that holds the terrains' textures (None: the packaged
            textures); a world with photo textures brings its own.
        transitions: names of the terrains of transition strips (a visit too short to form a
            context: the context scores leave them out).
    """

    def __init__(
        self,
        labels: np.ndarray,
        terrains: Sequence[Terrain],
        *,
        x_min_m: float,
        y_min_m: float,
        resolution_m: float,
        outside: str | None = None,
        mu_fields: Sequence[MuField | None] | None = None,
        textures=None,
        transitions: Sequence[str] = (),
    ) -> None:
        labels = np.asarray(labels)
        if labels.ndim != 2 or labels.size == 0:
            raise ValueError(f"labels must be a non-empty 2-D image, got shape {labels.shape}")
        if not np.issubdtype(labels.dtype, np.integer):
            raise ValueError(f"labels must have an integer dtype, got {labels.dtype}")
        terrains = list(terrains)
        if not terrains or len(terrains) > UNKNOWN:
            raise ValueError(f"need between 1 and {UNKNOWN} terrains, got {len(terrains)}")
        names = [t.name for t in terrains]
        if len(set(names)) != len(names):
            raise ValueError(f"terrain names must be unique, got {names}")
        if labels.min() < 0 or labels.max() > UNKNOWN:
            present = np.unique(labels)
        else:
            present = _present_labels(labels)
        bad = np.setdiff1d(present, [*range(len(terrains)), UNKNOWN])
        if bad.size:
            raise ValueError(
                f"labels contain values {bad.tolist()} that name no terrain "
                f"(valid: 0..{len(terrains) - 1}, or {UNKNOWN} for none)"
            )
        if not (np.isfinite(resolution_m) and resolution_m > 0):
            raise ValueError(f"resolution_m must be positive, got {resolution_m!r}")
        if not (np.isfinite(x_min_m) and np.isfinite(y_min_m)):
            raise ValueError(f"map origin must be finite, got ({x_min_m!r}, {y_min_m!r})")
        self.terrains: list[Terrain] = terrains
        self.labels: np.ndarray = np.ascontiguousarray(labels, dtype=np.uint8)
        self.labels.flags.writeable = False
        self.resolution_m = float(resolution_m)
        self.x_min_m = float(x_min_m)
        self.y_min_m = float(y_min_m)
        rows, cols = self.labels.shape
        self.x_max_m = self.x_min_m + cols * self.resolution_m
        self.y_max_m = self.y_min_m + rows * self.resolution_m
        self._name_to_index = {n: i for i, n in enumerate(names)}
        self.outside = outside
        if outside is None:
            self._outside_index = -1
        elif outside in self._name_to_index:
            self._outside_index = self._name_to_index[outside]
        else:
            raise ValueError(f"outside terrain {outside!r} is not one of {names}")
        self._mu = np.array([t.mu for t in terrains], dtype=float)
        self._names = np.array(names, dtype=object)
        # Python-level copies for the single-point fast path (the plant calls it on every
        # derivative evaluation): a memoryview reads one cell as a Python int without a numpy
        # scalar, and the raster is read-only, so the view never goes stale.
        self._inv_res = 1.0 / self.resolution_m
        self._mu_list = self._mu.tolist()
        self._cells = memoryview(self.labels)
        self._rows, self._cols = rows, cols
        fields = list(mu_fields) if mu_fields is not None else [None] * len(terrains)
        if len(fields) != len(terrains):
            raise ValueError(f"mu_fields needs one entry per terrain, got {len(fields)}")
        self.mu_fields: list[MuField | None] = fields
        self._any_field = any(f is not None for f in fields)
        self.textures = textures
        unknown = sorted(set(transitions) - set(names))
        if unknown:
            raise ValueError(f"transitions {unknown} are not terrains of the map ({names})")
        self.transitions: tuple[str, ...] = tuple(transitions)

    # ----------------------------------------------------------------------------- construction
    @classmethod
    def from_label_image(
        cls,
        labels: np.ndarray,
        terrains: Sequence[Terrain],
        *,
        x_min_m: float,
        y_min_m: float,
        resolution_m: float,
        outside: str | None = None,
    ) -> TerrainMap:
        """A map from a label image (row 0 north) placed with its south-west corner at
        ``(x_min_m, y_min_m)`` and ``resolution_m`` metres per pixel."""
        return cls(
            labels,
            terrains,
            x_min_m=x_min_m,
            y_min_m=y_min_m,
            resolution_m=resolution_m,
            outside=outside,
        )

    @classmethod
    def from_polygons(
        cls,
        regions: Sequence[tuple[Terrain, np.ndarray]],
        *,
        bounds_m: tuple[float, float, float, float],
        resolution_m: float = 0.05,
        outside: str | None = None,
    ) -> TerrainMap:
        """A map from ``(terrain, polygon)`` pairs, painted in order (later regions cover earlier
        ones). ``polygon`` is an (M, 2) array of world vertices [m], M >= 3.
        ``bounds_m = (x_min, x_max, y_min, y_max)``. Several regions may share a terrain (same
        object or an equal one with the same name)."""
        x_min, x_max, y_min, y_max = (float(b) for b in bounds_m)
        if not (x_max > x_min and y_max > y_min):
            raise ValueError(f"bounds_m must be (x_min, x_max, y_min, y_max), got {bounds_m}")
        rows, cols = raster_shape(bounds_m, resolution_m)
        labels = np.full((rows, cols), UNKNOWN, dtype=np.uint8)
        terrains: list[Terrain] = []
        index: dict[str, int] = {}
        for k, (terrain, polygon) in enumerate(regions):
            poly = np.asarray(polygon, dtype=float)
            if poly.ndim != 2 or poly.shape[1] != 2 or poly.shape[0] < 3:
                raise ValueError(
                    f"region {k} ({terrain.name}): polygon must be (M>=3, 2), got {poly.shape}"
                )
            if not np.all(np.isfinite(poly)):
                raise ValueError(f"region {k} ({terrain.name}): polygon has non-finite vertices")
            if terrain.name in index:
                if terrains[index[terrain.name]] != terrain:
                    raise ValueError(f"two different terrains are named {terrain.name!r}")
            else:
                index[terrain.name] = len(terrains)
                terrains.append(terrain)
            paint_polygon(labels, poly, index[terrain.name], x_min, y_max, resolution_m)
        if not terrains:
            raise ValueError("from_polygons needs at least one region")
        return cls(
            labels,
            terrains,
            x_min_m=x_min,
            y_min_m=y_min,
            resolution_m=resolution_m,
            outside=outside,
        )

    # ----------------------------------------------------------------------------- look-ups
    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the raster [m]."""
        return (self.x_min_m, self.x_max_m, self.y_min_m, self.y_max_m)

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.terrains]

    def terrain(self, name: str) -> Terrain:
        """The terrain called ``name``."""
        if name not in self._name_to_index:
            raise ValueError(f"unknown terrain {name!r}; this map has {self.names}")
        return self.terrains[self._name_to_index[name]]

    def index_of(self, name: str) -> int:
        """Label index of the terrain called ``name``."""
        self.terrain(name)
        return self._name_to_index[name]

    def world_to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) float raster coordinates of world points ``xy`` (..., 2), cell centres at
        integer + 0.5 (i.e. ``floor`` gives the cell)."""
        xy = np.asarray(xy, dtype=float)
        col = (xy[..., 0] - self.x_min_m) * self._inv_res
        row = (self.y_max_m - xy[..., 1]) * self._inv_res
        return row, col

    def index_at(self, xy: np.ndarray) -> np.ndarray | int:
        """Terrain index at world points ``xy`` [m]: (N, 2) -> (N,) int array; (2,) -> int."""
        xy_arr = np.asarray(xy, dtype=float)
        if xy_arr.shape == (2,):
            return self._index_at_point(float(xy_arr[0]), float(xy_arr[1]))
        if xy_arr.ndim != 2 or xy_arr.shape[1] != 2:
            raise ValueError(f"xy must have shape (N, 2) or (2,), got {xy_arr.shape}")
        if not np.all(np.isfinite(xy_arr)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(xy_arr), axis=1))[0])
            raise ValueError(f"xy[{bad}] = {xy_arr[bad].tolist()} is not finite")
        row_f, col_f = self.world_to_cell(xy_arr)
        row = np.floor(row_f).astype(np.int64)
        col = np.floor(col_f).astype(np.int64)
        rows, cols = self.labels.shape
        inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
        out = np.full(xy_arr.shape[0], UNKNOWN, dtype=np.int64)
        out[inside] = self.labels[row[inside], col[inside]]
        unknown = out == UNKNOWN
        if np.any(unknown):
            if self._outside_index < 0:
                k = int(np.flatnonzero(unknown)[0])
                raise ValueError(self._unknown_message(xy_arr[k, 0], xy_arr[k, 1], inside[k]))
            out[unknown] = self._outside_index
        return out

    def _index_at_point(self, x: float, y: float) -> int:
        """Terrain index at one world point (Python floats), the same cell and errors as
        :meth:`index_at` on an (N, 2) array, without numpy on the way (math.floor of a finite
        float equals numpy's floor)."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"xy = [{x}, {y}] is not finite")
        col = math.floor((x - self.x_min_m) * self._inv_res)
        row = math.floor((self.y_max_m - y) * self._inv_res)
        inside = 0 <= row < self._rows and 0 <= col < self._cols
        k = self._cells[row, col] if inside else UNKNOWN
        if k == UNKNOWN:
            if self._outside_index < 0:
                raise ValueError(self._unknown_message(x, y, inside))
            return self._outside_index
        return k

    def mu_and_index_at_point(self, x: float, y: float) -> tuple[float, int]:
        """(true mu, terrain index) at one world point ``(x, y)`` [m] given as two floats: the
        values of :meth:`mu_and_index_at` on ``[x, y]``, for callers that look up one point at
        a time (the plant, on every derivative evaluation)."""
        k = self._index_at_point(float(x), float(y))
        return float(self._point_mu(k, x, y)), k

    def _point_mu(self, k: int, x: float, y: float):
        """The true mu at one point ``(x, y)`` [m] of terrain ``k``: the terrain's mu, or its
        :class:`MuField` there."""
        field = self.mu_fields[k] if self._any_field else None
        if field is None:
            return self._mu_list[k]
        return field.mu(self._mu_list[k], np.array([[x, y]], dtype=float))[0]

    def _unknown_message(self, x: float, y: float, inside: bool) -> str:
        if not inside:
            x0, x1, y0, y1 = self.bounds_m
            return (
                f"point ({x:.3f}, {y:.3f}) m is outside the terrain map "
                f"(x in [{x0:g}, {x1:g}], y in [{y0:g}, {y1:g}] m) and the map has no "
                "'outside' terrain"
            )
        return f"point ({x:.3f}, {y:.3f}) m lies on no terrain region of the map"

    def mu_at(self, xy: np.ndarray) -> np.ndarray | float:
        """True friction coefficient at world points: (N, 2) -> (N,); (2,) -> float. The
        terrain's mu plus its :class:`MuField` where it has one."""
        return self.mu_and_index_at(xy)[0]

    def mu_and_index_at(self, xy: np.ndarray) -> tuple[np.ndarray | float, np.ndarray | int]:
        """(true mu, terrain index) at world points (shapes as :meth:`mu_at`)."""
        k = self.index_at(xy)
        if isinstance(k, int):
            xy_arr = np.asarray(xy, dtype=float)
            return self._point_mu(k, xy_arr[0], xy_arr[1]), k
        mu = self._mu[k]
        if self._any_field:
            xy_arr = np.asarray(xy, dtype=float)
            for j, field in enumerate(self.mu_fields):
                on = k == j
                if field is not None and np.any(on):
                    mu[on] = field.mu(self._mu_list[j], xy_arr[on])
        return mu, k

    def name_at(self, xy: np.ndarray) -> np.ndarray | str:
        """Terrain name at world points: (N, 2) -> (N,) object array of str; (2,) -> str."""
        k = self.index_at(xy)
        if isinstance(k, int):
            return self.terrains[k].name
        return self._names[k]


class MuField:
    """A smooth spatial variation of mu: values on a regular grid (bilinear in between) added to
    a terrain's mu, the sum kept within [``floor``, 2].

    Args:
        offsets: (R, C) offsets [-] on grid nodes; node (i, j) is at
            ``(x0_m + j * spacing_m, y0_m + i * spacing_m)``.
    """

    def __init__(
        self, offsets: np.ndarray, *, x0_m: float, y0_m: float, spacing_m: float, floor=0.02
    ):
        self.offsets = np.asarray(offsets, dtype=float)
        if self.offsets.ndim != 2 or min(self.offsets.shape) < 2:
            raise ValueError(f"MuField offsets must be (R>=2, C>=2), got {self.offsets.shape}")
        self.x0_m, self.y0_m, self.spacing_m = float(x0_m), float(y0_m), float(spacing_m)
        self.floor = float(floor)

    @classmethod
    def gaussian(
        cls,
        bounds_m: tuple[float, float, float, float],
        *,
        amplitude: float,
        length_scale_m: float,
        seed: int,
    ) -> MuField:
        """A Gaussian random field over ``bounds_m`` of standard deviation ``amplitude`` and
        correlation length ``length_scale_m`` [m], drawn from ``seed``: white noise on a grid of
        a quarter of the length scale, smoothed by a Gaussian kernel, scaled to unit variance."""
        from scipy.ndimage import gaussian_filter

        x0, x1, y0, y1 = bounds_m
        spacing = length_scale_m / 4.0
        cols = int(np.ceil((x1 - x0) / spacing)) + 2
        rows = int(np.ceil((y1 - y0) / spacing)) + 2
        noise = np.random.default_rng(seed).standard_normal((rows, cols))
        smooth = gaussian_filter(noise, sigma=length_scale_m / spacing / 2.0, mode="wrap")
        std = float(smooth.std())
        offsets = amplitude * smooth / std if std > 0 else np.zeros_like(smooth)
        return cls(offsets, x0_m=x0 - spacing / 2, y0_m=y0 - spacing / 2, spacing_m=spacing)

    def offset_at(self, xy: np.ndarray) -> np.ndarray:
        """Offsets at world points (N, 2) [m] -> (N,) (bilinear; clamped at the grid's edge)."""
        rows, cols = self.offsets.shape
        fx = np.clip((xy[:, 0] - self.x0_m) / self.spacing_m, 0.0, cols - 1.000001)
        fy = np.clip((xy[:, 1] - self.y0_m) / self.spacing_m, 0.0, rows - 1.000001)
        j, i = fx.astype(int), fy.astype(int)
        tx, ty = fx - j, fy - i
        o = self.offsets
        top = o[i, j] * (1 - tx) + o[i, j + 1] * tx
        bottom = o[i + 1, j] * (1 - tx) + o[i + 1, j + 1] * tx
        return top * (1 - ty) + bottom * ty

    def mu(self, base_mu: float, xy: np.ndarray) -> np.ndarray:
        """``base_mu`` plus the offsets at ``xy`` (N, 2), within [floor, 2]."""
        return np.clip(base_mu + self.offset_at(xy), self.floor, 2.0)


def _present_labels(labels: np.ndarray) -> np.ndarray:
    """Sorted label values (0..255) present in ``labels``, a histogram over 0..255 (never a
    whole-raster copy into a wider integer type: a 24 Mcell map would need 192 MB)."""
    if labels.dtype == np.uint8:
        hist = cv2.calcHist([np.ascontiguousarray(labels)], [0], None, [256], [0, 256])
        return np.flatnonzero(hist.ravel())
    flat = labels.reshape(-1)
    counts = np.zeros(256, dtype=np.int64)
    block = 1 << 22
    for start in range(0, flat.size, block):
        counts += np.bincount(flat[start : start + block].astype(np.intp), minlength=256)[:256]
    return np.flatnonzero(counts)


def paint_polygon(
    labels: np.ndarray,
    polygon_m: np.ndarray,
    value: int,
    x_min_m: float,
    y_max_m: float,
    resolution_m: float,
) -> None:
    """Set the cells of raster ``labels`` (row 0 at ``y_max_m``, column 0 at ``x_min_m``) whose
    centre lies inside ``polygon_m`` ((M, 2) world vertices [m]) to ``value``."""
    poly = np.asarray(polygon_m, dtype=float)
    # Pixel coordinates with integer values at cell centres (OpenCV's convention).
    u = (poly[:, 0] - x_min_m) / resolution_m - 0.5
    v = (y_max_m - poly[:, 1]) / resolution_m - 0.5
    _rasterise_polygon(labels, np.stack([u, v], axis=1), value)


def _rasterise_polygon(labels: np.ndarray, uv: np.ndarray, value: int) -> None:
    """Set ``labels`` to ``value`` on the cells whose centre (integer pixel coordinates) lies
    inside polygon ``uv`` (M, 2, pixel coordinates; even-odd rule). An exact scanline fill:
    each edge's crossings of the rows of cell centres (half-open in the row, so a vertex counts
    once), sorted along each row, pair up into the spans of cells inside. Works on the
    polygon's bounding box only."""
    rows, cols = labels.shape
    c0 = max(int(np.floor(uv[:, 0].min())), 0)
    c1 = min(int(np.ceil(uv[:, 0].max())) + 1, cols)
    r0 = max(int(np.floor(uv[:, 1].min())), 0)
    r1 = min(int(np.ceil(uv[:, 1].max())) + 1, rows)
    if c1 <= c0 or r1 <= r0:
        return
    u0, v0 = uv[:, 0], uv[:, 1]
    u1, v1 = np.roll(u0, -1), np.roll(v0, -1)
    keep = v0 != v1
    u0, v0, u1, v1 = u0[keep], v0[keep], u1[keep], v1[keep]
    first = np.clip(np.ceil(np.minimum(v0, v1)), r0, r1).astype(np.int64)
    stop = np.clip(np.ceil(np.maximum(v0, v1)), r0, r1).astype(np.int64)
    count = stop - first
    edge = np.repeat(np.arange(u0.size), count)
    row = first[edge] + (np.arange(edge.size) - np.repeat(np.cumsum(count) - count, count))
    x = u0[edge] + (row - v0[edge]) * ((u1 - u0) / (v1 - v0))[edge]
    col = np.clip(np.ceil(x), c0, c1).astype(np.int64) - c0
    order = np.lexsort((col, row))
    row, col = row[order], col[order]
    # Consecutive crossings of a row pair up (even-odd): cells [col[2k], col[2k+1]) are inside.
    starts, ends, span_rows = col[0::2], col[1::2], row[0::2]
    block = labels[:, c0:c1]
    for r, a, b in zip(span_rows.tolist(), starts.tolist(), ends.tolist(), strict=True):
        if b > a:
            block[r, a:b] = value
