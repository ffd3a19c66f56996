"""3-D projection of stored feature vectors for the ``/pcvfe/features`` layer.

A PCA is fitted to the store at each re-clustering (the principal axes of the stored vectors),
the three leading components are scaled so the fitted cloud fits a cube of ``size_m`` and placed
at ``origin_m``; new frames are projected with the same fit until the next one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PcaProjection:
    """A fitted projection z (D,) -> point (3,) [m] in the Meshcat scene.

    Attributes:
        mean: (D,) mean of the fitted vectors.
        axes: (3, D) orthonormal principal axes (rows; zero rows when D or the data have fewer
            than three directions).
        scale_m: metres per feature unit.
        origin_m: (3,) where the mean lands.
        explained: (3,) fraction of the variance each axis explains.
    """

    mean: np.ndarray
    axes: np.ndarray
    scale_m: float
    origin_m: np.ndarray
    explained: np.ndarray

    @classmethod
    def fit(cls, z: np.ndarray, *, size_m: float = 20.0, origin_m=(0.0, 0.0, 0.0)):
        """Fit to ``z`` (N, D), N >= 1, finite rows only; the cloud then spans about ``size_m``."""
        z = np.asarray(z, dtype=float)
        if z.ndim != 2 or z.shape[0] == 0:
            raise ValueError(f"PcaProjection.fit: z must be (N>=1, D) vectors, got {z.shape}")
        z = z[np.all(np.isfinite(z), axis=1)]
        if len(z) == 0:
            raise ValueError("PcaProjection.fit: no finite feature vectors to fit")
        mean = z.mean(axis=0)
        centred = z - mean
        _, sing, vt = np.linalg.svd(centred, full_matrices=False)
        k = min(3, vt.shape[0])
        axes = np.zeros((3, z.shape[1]))
        axes[:k] = vt[:k]
        # Sign convention: the largest loading of each axis is positive (a stable picture).
        for i in range(k):
            j = int(np.argmax(np.abs(axes[i])))
            if axes[i, j] < 0:
                axes[i] = -axes[i]
        var = sing**2
        explained = np.zeros(3)
        if var.sum() > 0:
            explained[:k] = var[:k] / var.sum()
        proj = centred @ axes.T
        extent = float(np.max(np.abs(proj))) if proj.size else 0.0
        scale = size_m / (2.0 * extent) if extent > 1e-12 else 1.0
        return cls(mean, axes, scale, np.asarray(origin_m, dtype=float).reshape(3), explained)

    def project(self, z: np.ndarray) -> np.ndarray:
        """Points [m] (N, 3) of vectors ``z`` (N, D) or (3,) of one vector (D,)."""
        z = np.asarray(z, dtype=float)
        if z.shape[-1] != self.mean.shape[0]:
            raise ValueError(
                f"PcaProjection.project: vectors of dimension {z.shape[-1]}, fitted to "
                f"{self.mean.shape[0]}"
            )
        return self.origin_m + self.scale_m * ((z - self.mean) @ self.axes.T)


def centroids(points: np.ndarray, labels: np.ndarray) -> dict[int, np.ndarray]:
    """Mean point (3,) of each label >= 0 (noise, label < 0, has none)."""
    points = np.asarray(points, dtype=float)
    labels = np.asarray(labels).astype(int).reshape(-1)
    return {int(k): points[labels == k].mean(axis=0) for k in np.unique(labels[labels >= 0])}
