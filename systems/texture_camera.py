"""TextureCamera: the downward camera under the car as a Drake system."""

from __future__ import annotations

import math

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, EventStatus, LeafSystem, State
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.perception.camera import CameraConfig, DownwardCamera
from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.perception.texture_library import TextureSet
from pcvfe_drake.vehicle.single_track import NX


def to_drake_image(rgb: np.ndarray) -> ImageRgba8U:
    """An opaque Drake ``ImageRgba8U`` holding an RGB uint8 (H, W, 3) array (OpenCV adds the
    alpha in one contiguous pass: 33 us at 224 px, where numpy's strided writes of the colour
    and the alpha took 440 us)."""
    h, w, _ = rgb.shape
    image = ImageRgba8U(w, h)
    image.mutable_data[...] = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2RGBA)
    return image


class TextureCamera(LeafSystem):
    """Downward camera: renders the textured ground under the car at its own frame rate.

    .. pydrake_system::

        name: TextureCamera
        input_ports:
        - state
        output_ports:
        - image

    Ports:
        state: input (7), the single-track state ``[sx m, sy m, delta rad, v m/s, psi rad,
            psi_dot rad/s, beta rad]``; the pose ``(sx, sy, psi)`` places the view, ``v`` sets
            the motion blur.
        image: output, abstract ``ImageRgba8U`` (``config.width_px`` x ``config.height_px``,
            alpha 255), from state: the latest frame, held between frames (no feedthrough).

    Rate: a periodic unrestricted update every ``period_s`` (default 0.1 s = 10 Hz, offset 0)
    renders a frame with :class:`pcvfe_drake.perception.camera.DownwardCamera` and stores it in
    abstract
    state; an initialization event renders the first frame, so the output is valid from t = 0.
    The random effects of frame k (taken at t = k * period_s) use
    ``numpy.random.default_rng([seed, k])``: a run is reproducible from its seed and no random
    state is hidden in the system. A non-finite state, or a view centre off the terrain map,
    raises ``ValueError`` naming the value.
    """

    def __init__(
        self,
        terrain_map: TerrainMap,
        config: CameraConfig | None = None,
        *,
        period_s: float = 0.1,
        seed: int = 0,
        textures: TextureSet | None = None,
    ) -> None:
        super().__init__()
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s must be a positive number of seconds, got {period_s!r}")
        if not (isinstance(seed, int | np.integer) and seed >= 0):
            raise ValueError(f"seed must be a non-negative int, got {seed!r}")
        self._camera = DownwardCamera(terrain_map, config, textures)
        self._period_s = float(period_s)
        self._seed = int(seed)
        cfg = self._camera.config

        self._state_port = self.DeclareVectorInputPort("state", NX)
        blank = ImageRgba8U(cfg.width_px, cfg.height_px)
        self._frame_index = self.DeclareAbstractState(AbstractValue.Make(blank))
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self._period_s, offset_sec=0.0, update=self._on_frame
        )
        self.DeclareInitializationUnrestrictedUpdateEvent(self._on_frame)
        self._image_port = self.DeclareStateOutputPort("image", self._frame_index)

    @property
    def camera(self) -> DownwardCamera:
        """The core camera model (configuration, terrain map, renderer)."""
        return self._camera

    @property
    def period_s(self) -> float:
        """Frame period [s]."""
        return self._period_s

    def frame_rng(self, time_s: float) -> np.random.Generator:
        """The random generator of the frame taken at ``time_s``."""
        k = int(round(time_s / self._period_s))
        return np.random.default_rng([self._seed, k])

    def _on_frame(self, context: Context, state: State) -> EventStatus:
        x = np.asarray(self._state_port.Eval(context), dtype=float)
        if not np.all(np.isfinite(x)):
            raise ValueError(
                f"TextureCamera: input 'state' = {x.tolist()} is not finite at "
                f"t = {context.get_time():.3f} s"
            )
        rgb = self._camera.render_state(x, self.frame_rng(context.get_time()))
        state.get_mutable_abstract_state(self._frame_index).set_value(to_drake_image(rgb))
        return EventStatus.Succeeded()
