"""Texture-descriptor backend: time per camera frame and nearest-centroid accuracy.

Frames: every texture of ``textures/`` seen by the downward camera (224 x 224) at random
positions, headings (rotation) and speeds 0-15 m/s with motion blur (4 ms exposure), exposure
jitter 0.15 and sensor noise 2 or 8. Accuracy: nearest centroid (centroids from training frames)
on held-out frames. Timing (CPU time of the process, robust to other jobs on the machine): ours
(``DescriptorExtractor``: OpenCV resize, Lab conversion, Laplacian pyramid, Sobel, structure
tensor) against a straightforward scikit-image / scipy implementation of the same quantities,
measured in the same run on the same frames.

Usage: python benchmarks/features_descriptor.py [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from scipy import ndimage
from skimage import color, filters, transform

from pcvfe_drake.perception.camera import CameraConfig, DownwardCamera
from pcvfe_drake.perception.features import DescriptorExtractor
from pcvfe_drake.perception.terrain import Terrain, TerrainMap
from pcvfe_drake.perception.texture_library import TextureSet

BUDGET_MS = 5.0


def skimage_descriptor(rgb: np.ndarray, n: int = 112) -> np.ndarray:
    """The same kind of descriptor written the straightforward way with scikit-image/scipy."""
    small = transform.resize(rgb, (n, n), anti_aliasing=True)
    lab = color.rgb2lab(small)
    L, a, b = lab[..., 0], lab[..., 1], lab[..., 2]
    p10, p90 = np.percentile(L, (10, 90))
    chroma = np.hypot(a, b)
    colour = [L.mean() / 100, a.mean() / 20, b.mean() / 20, L.std() / 25, a.std() / 10,
              b.std() / 10, p10 / 100, p90 / 100, chroma.mean() / 20]  # fmt: skip
    bands = [np.log1p(np.abs(band).mean()) / 3
             for band in list(transform.pyramid_laplacian(L, max_layer=3))[:4]]  # fmt: skip
    ab_bands = []
    for ch in (a, b):
        pyr = list(transform.pyramid_laplacian(ch, max_layer=2))
        ab_bands.append([np.abs(pyr[0]).mean(), np.abs(pyr[1]).mean()])
    ab_bands = [np.log1p(np.mean([x[i] for x in ab_bands])) / 2 for i in range(2)]
    g = transform.pyramid_reduce(L, 2)
    gx, gy = filters.sobel_v(g), filters.sobel_h(g)
    mag = np.hypot(gx, gy)
    coh = []
    for s in (1.5, 4.0):
        jxx = ndimage.gaussian_filter(gx * gx, s)
        jyy = ndimage.gaussian_filter(gy * gy, s)
        jxy = ndimage.gaussian_filter(gx * gy, s)
        coh.append(np.sqrt((jxx - jyy) ** 2 + 4 * jxy**2).sum() / max((jxx + jyy).sum(), 1e-9))
    grad = [np.log1p(mag.mean()) / 2, (mag > 4.0).mean(), *coh]
    return np.array(colour + bands + ab_bands + grad + [(L < 20).mean()])


def camera_frames(textures: TextureSet, n_per: int, rng: np.random.Generator):
    frames, labels = [], []
    for k, name in enumerate(textures.names):
        world = TerrainMap.from_label_image(
            np.zeros((1, 1), np.uint8), [Terrain(name, 0.5, name)], x_min_m=0, y_min_m=0,
            resolution_m=1.0, outside=name,
        )  # fmt: skip
        cams = [
            DownwardCamera(
                world,
                CameraConfig(exposure_s=0.004, exposure_jitter=0.15, noise_std=noise),
                textures,
            )  # fmt: skip
            for noise in (2.0, 8.0)
        ]
        for i in range(n_per):
            x, y = rng.uniform(-50, 50, 2)
            psi, v = rng.uniform(-np.pi, np.pi), rng.uniform(0, 15)
            frames.append(cams[i % 2].render(x, y, psi, v, rng))
            labels.append(k)
    return frames, np.array(labels)


def nearest_centroid_accuracy(z: np.ndarray, y: np.ndarray, n_per: int) -> float:
    train = np.tile(np.arange(n_per) < n_per // 2, y.max() + 1)
    centroids = np.array([z[train & (y == k)].mean(axis=0) for k in range(y.max() + 1)])
    d = ((z[~train][:, None] - centroids[None]) ** 2).sum(axis=2)
    return float(np.mean(np.argmin(d, axis=1) == y[~train]))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="20 instead of 60 frames per texture")
    args = parser.parse_args()
    n_per = 20 if args.quick else 60
    textures = TextureSet()
    rng = np.random.default_rng(2024)
    frames, y = camera_frames(textures, n_per, rng)
    print(f"features_descriptor: {len(frames)} frames of {len(textures.names)} textures")

    ext = DescriptorExtractor()
    ext.semantic(frames[:5])  # warm-up
    c0 = time.process_time()
    z = ext.semantic(frames)
    ours_ms = (time.process_time() - c0) / len(frames) * 1e3
    acc = nearest_centroid_accuracy(z, y, n_per)
    print(f"  ours: {ours_ms:.3f} ms/frame CPU, nearest-centroid accuracy {acc:.4f}")

    n_base = len(frames) if not args.quick else min(len(frames), 120)
    sub = np.linspace(0, len(frames) - 1, n_base).astype(int)
    c0 = time.process_time()
    z_base = np.array([skimage_descriptor(frames[i]) for i in sub])
    base_ms = (time.process_time() - c0) / n_base * 1e3
    base_acc = nearest_centroid_accuracy(z_base, y[sub], n_per) if n_base == len(frames) else None
    print(f"  scikit-image baseline: {base_ms:.2f} ms/frame CPU"
          + (f", accuracy {base_acc:.4f}" if base_acc is not None else ""))  # fmt: skip
    result = {
        "benchmark": "features_descriptor",
        "frames": len(frames),
        "textures": len(textures.names),
        "dim": ext.dim,
        "nearest_centroid_accuracy": round(acc, 4),
        "accuracy_target": 0.95,
        "cpu_ms_per_frame": round(ours_ms, 4),
        "budget_ms": BUDGET_MS,
        "within_budget": bool(ours_ms <= BUDGET_MS),
        "baseline_skimage_cpu_ms_per_frame": round(base_ms, 3),
        "baseline_accuracy": None if base_acc is None else round(base_acc, 4),
        "speedup_vs_skimage": round(base_ms / ours_ms, 1),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
