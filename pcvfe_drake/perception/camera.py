"""Downward-looking camera under the car: renders the textured ground from a terrain map.

Camera model: a pinhole camera at ``height_m`` above flat ground looking straight down, square
pixels, field of view ``fov_deg`` across the image width. It sits ``forward_offset_m`` ahead of
the car's reference point along the heading. Image axes: the top of the image points in the
heading direction, the right of the image to the car's right. The ground under the view is drawn
by :class:`pcvfe_drake.perception.ground_render.GroundRenderer` (one affine warp per visible
terrain), so
region boundaries are visible when the view straddles them.

Optional effects (all off by default; randomness only from the ``rng`` passed to ``render``):
- motion blur along the image's forward axis, ``v_mps * exposure_s`` metres long (grows with
  speed; the side-slip direction is ignored), length jittered by +-10 % per frame;
- exposure changes: a per-frame gain ``exp(N(0, exposure_jitter))``;
- sensor noise: additive Gaussian noise with standard deviation ``noise_std`` (0-255 scale,
  rounded to integers), drawn as a random window of a fixed, precomputed noise field (fast,
  and still seeded).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pcvfe_drake.perception.ground_render import GroundRenderer
from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.perception.texture_library import TextureSet
from pcvfe_drake.vehicle.single_track import PSI, SX, SY, V

_NOISE_FIELD_SEED = 20240607  # fixed seed of the precomputed unit-variance noise field


@dataclass
class CameraConfig:
    """Downward camera settings (units in the names)."""

    height_m: float = 1.0
    fov_deg: float = 60.0
    width_px: int = 224
    height_px: int = 224
    forward_offset_m: float = 0.0
    exposure_s: float = 0.0
    exposure_jitter: float = 0.0
    noise_std: float = 0.0

    def __post_init__(self) -> None:
        checks = {
            "height_m": self.height_m > 0,
            "fov_deg": 0 < self.fov_deg < 170,
            "width_px": int(self.width_px) == self.width_px and 8 <= self.width_px <= 4096,
            "height_px": int(self.height_px) == self.height_px and 8 <= self.height_px <= 4096,
            "forward_offset_m": np.isfinite(self.forward_offset_m),
            "exposure_s": 0 <= self.exposure_s <= 1.0,
            "exposure_jitter": 0 <= self.exposure_jitter <= 2.0,
            "noise_std": 0 <= self.noise_std <= 128.0,
        }
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"CameraConfig.{name} = {getattr(self, name)!r} is out of range")

    @property
    def footprint_width_m(self) -> float:
        """Width of the ground patch seen [m]."""
        return 2.0 * self.height_m * np.tan(np.deg2rad(self.fov_deg) / 2.0)

    @property
    def m_per_px(self) -> float:
        return self.footprint_width_m / self.width_px

    @property
    def has_random_effects(self) -> bool:
        return self.exposure_jitter > 0 or self.noise_std > 0 or self.exposure_s > 0


class DownwardCamera:
    """Renders (H, W, 3) RGB uint8 frames of the ground under a pose ``(x_m, y_m, psi_rad)``."""

    def __init__(
        self,
        terrain_map: TerrainMap,
        config: CameraConfig | None = None,
        textures: TextureSet | None = None,
    ) -> None:
        self.map = terrain_map
        self.config = config or CameraConfig()
        self.renderer = GroundRenderer(terrain_map, textures)
        self._noise_field: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.config.height_px, self.config.width_px, 3)

    def pixel_to_world(self, x_m: float, y_m: float, psi_rad: float) -> np.ndarray:
        """2x3 affine mapping pixel (col, row, 1) to world (x, y) [m] for a car pose."""
        cfg = self.config
        m = cfg.m_per_px
        c, s = np.cos(psi_rad), np.sin(psi_rad)
        px = x_m + cfg.forward_offset_m * c
        py = y_m + cfg.forward_offset_m * s
        cx = (cfg.width_px - 1) / 2.0
        cy = (cfg.height_px - 1) / 2.0
        # forward = (cy - row) m, right = (col - cx) m; right unit vector = (sin, -cos)
        return np.array(
            [
                [m * s, -m * c, px + cy * m * c - cx * m * s],
                [-m * c, -m * s, py + cy * m * s + cx * m * c],
            ]
        )

    def render(
        self,
        x_m: float,
        y_m: float,
        psi_rad: float,
        v_mps: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """Frame at the given pose and speed. ``rng`` drives the optional random effects and is
        required when any is configured (so frames are reproducible from a seed)."""
        for name, value in (("x_m", x_m), ("y_m", y_m), ("psi_rad", psi_rad), ("v_mps", v_mps)):
            if not np.isfinite(value):
                raise ValueError(f"camera pose {name} = {value!r} is not finite")
        a = self.pixel_to_world(x_m, y_m, psi_rad)
        cfg = self.config
        centre = a @ np.array([(cfg.width_px - 1) / 2.0, (cfg.height_px - 1) / 2.0, 1.0])
        self.map.index_at(centre)  # raises a clear error when the view centre is off the map
        image = self.renderer.render(a, (cfg.height_px, cfg.width_px))
        if cfg.has_random_effects:
            if rng is None:
                raise ValueError(
                    "this camera has blur/noise/exposure effects configured; pass rng "
                    "(a numpy Generator seeded from the scenario) to render"
                )
            image = self._apply_effects(image, abs(float(v_mps)), rng)
        return image

    def render_state(self, x: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """Frame for a single-track state ``x`` (7,) in the CommonRoad order."""
        x = np.asarray(x, dtype=float)
        if x.shape != (7,):
            raise ValueError(f"state must have shape (7,), got {x.shape}")
        return self.render(x[SX], x[SY], x[PSI], x[V], rng)

    # ------------------------------------------------------------------------- effects
    def _noise(self, rng: np.random.Generator) -> np.ndarray:
        """A random (H, W, 3) int16 window of the fixed noise field (std ``noise_std``)."""
        h, w, _ = self.shape
        if self._noise_field is None:
            field_rng = np.random.default_rng(_NOISE_FIELD_SEED)
            field = field_rng.standard_normal((2 * h, 2 * w, 3)) * self.config.noise_std
            self._noise_field = np.round(field).astype(np.int16)
        dy, dx = rng.integers(0, h), rng.integers(0, w)
        return self._noise_field[dy : dy + h, dx : dx + w]

    def _apply_effects(
        self, image: np.ndarray, speed_mps: float, rng: np.random.Generator
    ) -> np.ndarray:
        cfg = self.config
        jitter = rng.uniform(0.9, 1.1)  # drawn every frame so the stream of draws is fixed
        blur_px = speed_mps * cfg.exposure_s / cfg.m_per_px * jitter
        length = int(round(blur_px))
        if length >= 2:
            image = cv2.blur(image, (1, length), borderType=cv2.BORDER_REFLECT)
        if cfg.exposure_jitter > 0:
            gain = float(np.exp(rng.normal(0.0, cfg.exposure_jitter)))
            image = cv2.convertScaleAbs(image, alpha=gain)  # saturates at 255
        if cfg.noise_std > 0:
            image = cv2.add(image, np.ascontiguousarray(self._noise(rng)), dtype=cv2.CV_8U)
        return image
