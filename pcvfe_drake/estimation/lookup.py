"""The lookup-table baseline: a terrain class from the image mapped through a mu table (no pydrake).

The paper's "lookup method with friction values derived from a table": no learning during the
drive, no dynamics. How the table is made (:func:`build_lookup_table`):

1. **Labelled subset.** A list of texture names from the texture library (``textures/``) are the
   classes the table knows (``classes``); terrains outside it are unknown to the table.
2. **Prototypes.** For each class, ``frames_per_class`` camera frames are rendered by the same
   downward camera model the run uses (its exposure blur, gain jitter and noise), over a
   terrain of that texture alone, at random positions, headings and speeds (0-12 m/s), and
   turned into feature vectors by the same feature extractor as the PC-VFE pipeline (the
   scenario's backend). A class's prototype is the mean of its vectors (nearest-centroid).
3. **Rejection radius.** Each class's radius is ``reject_factor`` times the 99th percentile of
   its own frames' distances to its prototype; a frame farther than that from its nearest
   prototype is "unknown".
4. **mu table.** Each class's mu is the texture's ``mu`` in ``textures/index.yaml``: a table of
   literature values, fixed whatever the world or a scenario's ``terrains`` overrides set as the
   ground's real friction (a lookup table is exactly what does not know the ground's real value;
   on the shipped paper worlds the two agree, the best case for the baseline); a frame
   classified as unknown gets ``default_mu`` (default: the lowest mu in the table, the safe
   choice).

:meth:`LookupTable.classify` is nearest prototype plus rejection; ``mu_for`` maps a feature
vector to mu.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

UNKNOWN_CLASS = -1


@dataclass(frozen=True)
class LookupTable:
    """Classes, their prototypes (C, D), rejection radii (C,), mu per class and the default."""

    classes: tuple[str, ...]
    prototypes: np.ndarray
    radii: np.ndarray
    mu: tuple[float, ...]
    default_mu: float

    def __post_init__(self) -> None:
        c = len(self.classes)
        if c == 0:
            raise ValueError("LookupTable: no classes")
        if self.prototypes.shape[0] != c or self.radii.shape != (c,) or len(self.mu) != c:
            raise ValueError("LookupTable: classes, prototypes, radii and mu must match in length")
        if not (math.isfinite(self.default_mu) and self.default_mu > 0):
            raise ValueError(f"LookupTable: default_mu={self.default_mu!r} must be > 0")

    @property
    def dim(self) -> int:
        return int(self.prototypes.shape[1])

    def classify(self, z) -> tuple[int, float]:
        """(class index or ``UNKNOWN_CLASS``, distance to the nearest prototype) of features z."""
        z = np.asarray(z, dtype=float).reshape(-1)
        if z.shape != (self.dim,) or not np.all(np.isfinite(z)):
            return UNKNOWN_CLASS, math.inf
        d = np.linalg.norm(self.prototypes - z, axis=1)
        k = int(np.argmin(d))
        return (k if d[k] <= self.radii[k] else UNKNOWN_CLASS), float(d[k])

    def mu_for(self, z) -> float:
        """The table's mu for features ``z`` (``default_mu`` when unknown)."""
        k, _ = self.classify(z)
        return self.default_mu if k == UNKNOWN_CLASS else float(self.mu[k])


def table_from_features(
    features: Mapping[str, np.ndarray],
    mu: Mapping[str, float],
    *,
    default_mu: float | None = None,
    reject_factor: float = 1.5,
) -> LookupTable:
    """A table from labelled feature vectors per class ((N_k, D) each) and mu per class."""
    if not features:
        raise ValueError("table_from_features: no labelled classes")
    missing = sorted(set(features) - set(mu))
    if missing:
        raise ValueError(f"table_from_features: no mu for class(es) {missing}")
    if not (math.isfinite(reject_factor) and reject_factor > 0):
        raise ValueError(f"reject_factor={reject_factor!r} must be > 0")
    names = tuple(features)
    protos, radii = [], []
    for name in names:
        z = np.asarray(features[name], dtype=float)
        if z.ndim != 2 or len(z) < 2:
            raise ValueError(f"class {name!r}: needs at least 2 feature vectors, got {z.shape}")
        c = z.mean(axis=0)
        protos.append(c)
        radii.append(reject_factor * float(np.quantile(np.linalg.norm(z - c, axis=1), 0.99)))
    mus = tuple(float(mu[n]) for n in names)
    return LookupTable(
        names,
        np.array(protos),
        np.array(radii),
        mus,
        float(min(mus) if default_mu is None else default_mu),
    )


def render_texture_frames(
    texture: str, n: int, rng: np.random.Generator, camera_config=None, textures=None
) -> list[np.ndarray]:
    """``n`` downward camera frames of ``texture`` alone (random pose and speed 0-12 m/s)."""
    from pcvfe_drake.perception.camera import DownwardCamera
    from pcvfe_drake.perception.terrain import Terrain, TerrainMap

    world = TerrainMap.from_label_image(
        np.zeros((1, 1), np.uint8),
        [Terrain(texture, 0.5, texture)],
        x_min_m=0.0,
        y_min_m=0.0,
        resolution_m=1.0,
        outside=texture,
    )
    camera = DownwardCamera(world, camera_config, textures)
    frames = []
    for _ in range(int(n)):
        x, y = rng.uniform(-50.0, 50.0, 2)
        psi, v = rng.uniform(-math.pi, math.pi), rng.uniform(0.0, 12.0)
        frames.append(camera.render(x, y, psi, v, rng))
    return frames


def build_lookup_table(
    extractor,
    classes: Sequence[str],
    *,
    camera_config=None,
    textures=None,
    frames_per_class: int = 40,
    seed: int = 0,
    default_mu: float | None = None,
    reject_factor: float = 1.5,
) -> LookupTable:
    """The table of the module docstring for the labelled ``classes`` (texture names).

    ``extractor`` is a ``pcvfe_drake.perception.features.FeatureExtractor`` (the pipeline's);
    ``textures`` a ``TextureSet`` (default: the shipped library).
    """
    from pcvfe_drake.perception.texture_library import default_textures

    textures = textures if textures is not None else default_textures()
    unknown = sorted(set(classes) - set(textures.names))
    if unknown:
        raise ValueError(
            f"lookup classes {unknown} are not textures of the library "
            f"(known: {', '.join(textures.names)})"
        )
    if int(frames_per_class) < 2:
        raise ValueError(f"frames_per_class={frames_per_class!r} must be >= 2")
    rng = np.random.default_rng([int(seed), 11])
    feats = {
        name: extractor.extract(
            render_texture_frames(name, frames_per_class, rng, camera_config, textures)
        )
        for name in classes
    }
    mu = {name: textures.entry(name).mu for name in classes}
    return table_from_features(feats, mu, default_mu=default_mu, reject_factor=reject_factor)
