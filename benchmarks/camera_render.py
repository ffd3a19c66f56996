"""Downward-camera frame rendering (224 x 224) along a lap of the default course.

Ours: ``DownwardCamera.render`` (one affine warp per visible terrain, pre-tiled textures, the
scenario's default effects: 2 ms exposure blur, exposure jitter 0.05, noise 3). Baseline, in the
same run: the straightforward numpy renderer: world coordinates of every pixel, a terrain
look-up per pixel (``TerrainMap.index_at``), and bilinear texture sampling by numpy gathers on the
full-resolution textures, no effects. Frames are taken every 0.1 s at the course's cruise speed;
"boundary" frames are those whose view holds more than one terrain. Times are wall clock and CPU
time of the process (``time.process_time``: robust when other jobs share the machine); the
speed-up is a ratio of CPU times.

Usage: python benchmarks/camera_render.py [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from pcvfe_drake.control.course import load_course
from pcvfe_drake.diagrams.world_io import world_terrain_map
from pcvfe_drake.perception.camera import CameraConfig, DownwardCamera

BUDGET_MS = 2.0


def numpy_render(cam: DownwardCamera, x: float, y: float, psi: float) -> np.ndarray:
    """Per-pixel reference renderer (plain numpy)."""
    cfg = cam.config
    h, w = cfg.height_px, cfg.width_px
    rr, cc = np.mgrid[0:h, 0:w]
    a = cam.pixel_to_world(x, y, psi)
    px = np.stack([cc.ravel(), rr.ravel(), np.ones(h * w)], axis=0)
    xy = (a @ px).T
    labels = cam.map.index_at(xy)
    out = np.zeros((h * w, 3))
    textures = cam.renderer.textures
    for k in np.unique(labels):
        name = cam.map.terrains[k].texture
        tex = textures.image(name).astype(float)
        th, tw = tex.shape[:2]
        s = tw / textures.tile_m(name)
        sel = labels == k
        u = xy[sel, 0] * s
        v = -xy[sel, 1] * s
        u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
        fu, fv = (u - u0)[:, None], (v - v0)[:, None]
        u0, v0 = u0 % tw, v0 % th
        u1, v1 = (u0 + 1) % tw, (v0 + 1) % th
        out[sel] = (
            tex[v0, u0] * (1 - fu) * (1 - fv)
            + tex[v0, u1] * fu * (1 - fv)
            + tex[v1, u0] * (1 - fu) * fv
            + tex[v1, u1] * fu * fv
        )
    return np.clip(out + 0.5, 0, 255).astype(np.uint8).reshape(h, w, 3)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="a quarter lap, fewer baseline runs")
    args = parser.parse_args()

    terrain = world_terrain_map("paper")
    course = load_course()
    dt = 0.1
    n_frames = int(course.length / course.speed / dt)
    if args.quick:
        n_frames //= 4
    s = np.arange(n_frames) * course.speed * dt
    xs, ys, hs, _ = course.sample(s)
    cfg = CameraConfig(exposure_s=0.002, exposure_jitter=0.05, noise_std=3.0)
    cam = DownwardCamera(terrain, cfg)
    rng = np.random.default_rng(0)
    print(f"camera_render: {n_frames} frames along {course.name} at {course.speed} m/s, 10 Hz")

    for i in range(n_frames):  # warm-up pass: texture levels and tiles are built once per run
        cam.render(xs[i], ys[i], hs[i], course.speed, rng)
    times = np.empty(n_frames)
    cpu = np.empty(n_frames)
    boundary = np.zeros(n_frames, bool)
    for i in range(n_frames):
        a = cam.pixel_to_world(xs[i], ys[i], hs[i])
        boundary[i] = cam.renderer.visible_labels(a, (cfg.height_px, cfg.width_px))[0].size > 1
        c0, t0 = time.process_time(), time.perf_counter()
        cam.render(xs[i], ys[i], hs[i], course.speed, rng)
        times[i] = time.perf_counter() - t0
        cpu[i] = time.process_time() - c0
    ms = times * 1e3
    cpu_ms = cpu * 1e3
    print(f"  ours: wall mean {ms.mean():.3f} ms, median {np.median(ms):.3f} ms, "
          f"p95 {np.percentile(ms, 95):.3f} ms; CPU mean {cpu_ms.mean():.3f} ms; "
          f"boundary frames {boundary.sum()}")  # fmt: skip

    clean = DownwardCamera(terrain)
    n_base = 10 if args.quick else 40
    idx = np.linspace(0, n_frames - 1, n_base).astype(int)
    base_times, ours_clean, diffs = [], [], []
    for i in idx:
        c0 = time.process_time()
        ref = numpy_render(clean, xs[i], ys[i], hs[i])
        base_times.append(time.process_time() - c0)
        c0 = time.process_time()
        for _ in range(5):
            img = clean.render(xs[i], ys[i], hs[i])
        ours_clean.append((time.process_time() - c0) / 5)
        diffs.append(np.abs(img.astype(float) - ref).mean())
    base_ms = 1e3 * float(np.mean(base_times))
    ours_clean_ms = 1e3 * float(np.mean(ours_clean))
    print(f"  numpy per-pixel baseline: {base_ms:.2f} ms/frame CPU; ours without effects on the "
          f"same frames {ours_clean_ms:.3f} ms (mean abs pixel difference {np.mean(diffs):.1f}, "
          "from texture pre-shrinking)")  # fmt: skip
    result = {
        "benchmark": "camera_render",
        "frames": int(n_frames),
        "resolution": [cfg.width_px, cfg.height_px],
        "effects": {
            "exposure_s": cfg.exposure_s,
            "exposure_jitter": cfg.exposure_jitter,
            "noise_std": cfg.noise_std,
        },  # fmt: skip
        "cpu_ms_per_frame_mean": round(float(cpu_ms.mean()), 4),
        "cpu_ms_boundary_frame_mean": (
            round(float(cpu_ms[boundary].mean()), 4) if boundary.any() else None
        ),
        "ms_per_frame_mean": round(float(ms.mean()), 4),
        "ms_per_frame_median": round(float(np.median(ms)), 4),
        "ms_per_frame_p95": round(float(np.percentile(ms, 95)), 4),
        "boundary_frames": int(boundary.sum()),
        "ms_boundary_frame_mean": round(float(ms[boundary].mean()), 4) if boundary.any() else None,
        "baseline_numpy_cpu_ms_per_frame": round(base_ms, 3),
        "ours_no_effects_cpu_ms_per_frame": round(ours_clean_ms, 4),
        "speedup_vs_numpy": round(base_ms / ours_clean_ms, 1),
        "mean_abs_pixel_diff_vs_baseline": round(float(np.mean(diffs)), 2),
        "budget_ms": BUDGET_MS,
        "cpu_mean_within_budget": bool(cpu_ms.mean() <= BUDGET_MS),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "machine": platform.processor() or platform.machine(),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
