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

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

UNKNOWN = 255  # label of raster cells that no region covers
_SUBPIXEL_SHIFT = 8  # fixed-point bits for cv2.fillPoly vertex coordinates


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
        # Python-level copies for the single-point fast path (the plant calls it every step).
        self._inv_res = 1.0 / self.resolution_m
        self._mu_list = self._mu.tolist()

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
            # Pixel coordinates with integer values at cell centres (OpenCV's convention).
            u = (poly[:, 0] - x_min) / resolution_m - 0.5
            v = (y_max - poly[:, 1]) / resolution_m - 0.5
            uv = np.stack([u, v], axis=1)
            _rasterise_polygon(labels, uv, index[terrain.name])
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
        if not (np.isfinite(x) and np.isfinite(y)):
            raise ValueError(f"xy = [{x}, {y}] is not finite")
        col = int(np.floor((x - self.x_min_m) * self._inv_res))
        row = int(np.floor((self.y_max_m - y) * self._inv_res))
        rows, cols = self.labels.shape
        inside = 0 <= row < rows and 0 <= col < cols
        k = int(self.labels[row, col]) if inside else UNKNOWN
        if k == UNKNOWN:
            if self._outside_index < 0:
                raise ValueError(self._unknown_message(x, y, inside))
            return self._outside_index
        return k

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
        """True friction coefficient at world points: (N, 2) -> (N,); (2,) -> float."""
        k = self.index_at(xy)
        if isinstance(k, int):
            return self._mu_list[k]
        return self._mu[k]

    def name_at(self, xy: np.ndarray) -> np.ndarray | str:
        """Terrain name at world points: (N, 2) -> (N,) object array of str; (2,) -> str."""
        k = self.index_at(xy)
        if isinstance(k, int):
            return self.terrains[k].name
        return self._names[k]


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


def _rasterise_polygon(labels: np.ndarray, uv: np.ndarray, value: int) -> None:
    """Set ``labels`` to ``value`` on the cells whose centre (integer pixel coordinates) lies
    inside polygon ``uv`` (M, 2, pixel coordinates). ``cv2.fillPoly`` fills the interior
    quickly; cells within two pixels of an edge, where it can be off by a pixel, are decided
    exactly with ``matplotlib.path.Path``. Works on the polygon's bounding box only."""
    from matplotlib.path import Path as _Path

    rows, cols = labels.shape
    c0 = max(int(np.floor(uv[:, 0].min())) - 3, 0)
    c1 = min(int(np.ceil(uv[:, 0].max())) + 4, cols)
    r0 = max(int(np.floor(uv[:, 1].min())) - 3, 0)
    r1 = min(int(np.ceil(uv[:, 1].max())) + 4, rows)
    if c1 <= c0 or r1 <= r0:
        return
    local = uv - [c0, r0]
    pts = np.round(local * float(1 << _SUBPIXEL_SHIFT)).astype(np.int32)
    mask = np.zeros((r1 - r0, c1 - c0), dtype=np.uint8)
    cv2.fillPoly(mask, [pts], 1, cv2.LINE_8, _SUBPIXEL_SHIFT)
    band = np.zeros_like(mask)
    cv2.polylines(band, [pts], True, 1, 5, cv2.LINE_8, _SUBPIXEL_SHIFT)
    rr, cc = np.nonzero(band)
    if rr.size:
        mask[rr, cc] = _Path(local).contains_points(np.stack([cc, rr], axis=1).astype(float))
    labels[r0:r1, c0:c1][mask.view(bool)] = value


# --------------------------------------------------------------------------------- default map
DEFAULT_BOUNDS_M = (-150.0, 150.0, -100.0, 100.0)
"""Extent (x_min, x_max, y_min, y_max) [m] of the default map: the 260 m x 170 m slalom plus
margin for the camera's view."""


def default_terrains() -> dict[str, Terrain]:
    """The terrains of the default map, by name.

    The four quadrant terrains use the public PC-VFE simulator's friction values (patchy grass
    0.3, brick 0.8, sand 0.45, concrete 0.6). The paper's Fig. 4 shows dry soil where the
    simulator code says sand; here that quadrant is ``sand`` (texture ``sand``) and dry soil
    appears in a transition strip. Transition strips: ``gravel`` (mu 0.55) along x = 0 and
    ``dry_soil`` (mu 0.5) along y = 0.
    """
    return {
        "patchy_grass": Terrain("patchy_grass", 0.30, "patchy_grass"),
        "brick": Terrain("brick", 0.80, "brick"),
        "sand": Terrain("sand", 0.45, "sand"),
        "concrete": Terrain("concrete", 0.60, "concrete"),
        "gravel": Terrain("gravel", 0.55, "gravel"),
        "dry_soil": Terrain("dry_soil", 0.50, "dry_soil"),
    }


def _strip_edges(
    half_width_m: float, extent_m: float, phase: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges of a transition strip centred on a coordinate axis, with gently wavy deterministic
    edges (amplitude about 0.35 m): along-strip samples ``s`` [m] every 0.25 m over
    ``[-extent_m, extent_m]``, and the lower / upper edge offsets across the strip [m] there
    (linear in between)."""
    s = np.linspace(-extent_m, extent_m, int(2 * extent_m / 0.25) + 1)

    def wobble(s: np.ndarray, p: float) -> np.ndarray:
        return 0.25 * np.sin(2 * np.pi * s / 7.3 + p) + 0.12 * np.sin(2 * np.pi * s / 2.9 + 2 * p)

    return s, -half_width_m + wobble(s, phase), half_width_m + wobble(s, phase + 1.7)


def _paint_strip(
    labels: np.ndarray,
    along: np.ndarray,
    across: np.ndarray,
    edges: tuple[np.ndarray, np.ndarray, np.ndarray],
    value: int,
    *,
    rows_along: bool,
) -> None:
    """Set the cells whose centre lies between a strip's edges to ``value``. ``along`` are the
    cell-centre coordinates along the strip (columns if ``rows_along`` is False, else rows),
    ``across`` the ones across it. Only the band of cells the strip can reach is touched."""
    s, lo, hi = edges
    lo_at = np.interp(along, s, lo)
    hi_at = np.interp(along, s, hi)
    band = np.flatnonzero((across >= lo.min()) & (across <= hi.max()))
    if band.size == 0:
        return
    b0, b1 = int(band[0]), int(band[-1]) + 1
    c = across[b0:b1]
    if rows_along:  # strip along y (rows): band of columns
        mask = (c[None, :] >= lo_at[:, None]) & (c[None, :] <= hi_at[:, None])
        labels[:, b0:b1][mask] = value
    else:  # strip along x (columns): band of rows
        mask = (c[:, None] >= lo_at[None, :]) & (c[:, None] <= hi_at[None, :])
        labels[b0:b1, :][mask] = value


def default_terrain_map(
    *,
    strip_width_m: float = 3.0,
    resolution_m: float = 0.05,
    outside: str | None = None,
) -> TerrainMap:
    """The paper's simulation layout, centred on the world origin, x in [-150, 150] m,
    y in [-100, 100] m (``DEFAULT_BOUNDS_M``).

    Quadrants (counter-clockwise, the order a counter-clockwise lap meets them starting east):
    x > 0, y > 0 ``patchy_grass`` (mu 0.3); x < 0, y > 0 ``brick`` (0.8); x < 0, y < 0 ``sand``
    (0.45); x > 0, y < 0 ``concrete`` (0.6). Transition strips ``strip_width_m`` wide (wavy
    edges): ``gravel`` (0.55) along x = 0 and ``dry_soil`` (0.5) along y = 0, crossing at the
    origin. A course around the origin (the 260 m x 170 m ``slalom``, or its predecessor's
    120 m x 80 m at 1/5 scale, ``slalom_small``) crosses each quadrant for about a quarter of
    its length and each strip twice.

    At the default 5 cm raster the map is 6000 x 4000 cells (24 MB of labels). The raster is
    built once per (strip width, resolution) and shared, read-only, by the maps returned.
    """
    if not (np.isfinite(strip_width_m) and strip_width_m >= 0):
        raise ValueError(f"strip_width_m must be >= 0, got {strip_width_m!r}")
    if not (np.isfinite(resolution_m) and resolution_m > 0):
        raise ValueError(f"resolution_m must be positive, got {resolution_m!r}")
    labels, terrains = _default_raster(float(strip_width_m), float(resolution_m))
    x0, _, y0, _ = DEFAULT_BOUNDS_M
    return TerrainMap.from_label_image(
        labels, terrains, x_min_m=x0, y_min_m=y0, resolution_m=resolution_m, outside=outside
    )


@functools.lru_cache(maxsize=4)
def _default_raster(strip_width_m: float, resolution_m: float) -> tuple[np.ndarray, list]:
    """Label raster (read-only) and terrains of the default layout (see default_terrain_map).

    A cell belongs to a region when its centre does (as in ``from_polygons``): the quadrants
    are the signs of the centre's x and y, the strips the cells whose centre lies between the
    strip's piecewise-linear edges (``dry_soil`` along y = 0 first, ``gravel`` along x = 0 over
    it where they cross).
    """
    t = default_terrains()
    x0, x1, y0, y1 = DEFAULT_BOUNDS_M
    cols = int(round((x1 - x0) / resolution_m))
    rows = int(round((y1 - y0) / resolution_m))
    xc = x0 + (np.arange(cols) + 0.5) * resolution_m  # cell-centre x of each column
    yc = y1 - (np.arange(rows) + 0.5) * resolution_m  # cell-centre y of each row (north first)
    east = int(np.searchsorted(xc, 0.0))  # first column with x > 0
    north = int(np.count_nonzero(yc > 0.0))  # rows 0..north-1 have y > 0
    terrains = [t["patchy_grass"], t["brick"], t["sand"], t["concrete"]]
    labels = np.empty((rows, cols), dtype=np.uint8)
    labels[:north, east:] = 0  # patchy grass, x > 0, y > 0
    labels[:north, :east] = 1  # brick, x < 0, y > 0
    labels[north:, :east] = 2  # sand, x < 0, y < 0
    labels[north:, east:] = 3  # concrete, x > 0, y < 0
    if strip_width_m > 0:
        half = 0.5 * strip_width_m
        pad = 1.0
        terrains += [t["dry_soil"], t["gravel"]]
        dry = _strip_edges(half, x1 + pad, phase=0.3)
        _paint_strip(labels, xc, yc, dry, 4, rows_along=False)
        gravel = _strip_edges(half, y1 + pad, phase=1.1)
        _paint_strip(labels, yc, xc, gravel, 5, rows_along=True)
    labels.flags.writeable = False
    return labels, terrains
