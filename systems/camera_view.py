"""CameraView: what the camera saw and which context it was given, under ``/pcvfe/camera``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Meshcat, Rgba
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.runs.palette import context_rgb
from pcvfe_drake.systems.meshcat_layer import (
    ROOT,
    TextLabel,
    VisibleChoice,
    follow_car,
    set_image_quad,
)
from pcvfe_drake.vehicle.single_track import NX
from pcvfe_drake.views.labels import thumbnail

PATH = f"{ROOT}/camera"


class CameraView(LeafSystem):
    """The current camera frame on a panel that follows the car, framed in its context's colour.

    A vertical panel (facing south, -y) at ``offset_m`` from the car's position:

    - ``/pcvfe/camera/frame``: the frame shrunk to ``thumbnail_px`` square, ``panel_m`` wide,
      updated every ``frame_period_s`` (each update is its own object keyed visible for its
      time, so ``playback.html`` replays the frames);
    - ``/pcvfe/camera/border``: a frame behind it in the colour of the assigned context (black:
      noise, -1);
    - ``/pcvfe/camera/context``: the context id as text in that colour;
    - ``/pcvfe/camera/caption``: ``caption(z)`` of the frame's information vector, e.g. the top
      CLIP captions or the descriptor's nearest texture
      (:class:`pcvfe_drake.views.labels.FrameCaptioner`); absent without a ``caption``.

    ``context_id`` and ``features`` may be left unconnected (a loop without clustering or
    features): the border, id and caption are then not drawn.

    .. pydrake_system::

        name: CameraView
        input_ports:
        - image
        - state
        - context_id
        - features

    Rate: one periodic publish every ``frame_period_s`` (default 0.5 s).
    """

    def __init__(
        self,
        meshcat: Meshcat,
        feature_dim: int,
        *,
        caption: Callable[[np.ndarray], str] | None = None,
        frame_period_s: float = 0.5,
        thumbnail_px: int = 64,
        panel_m: float = 8.0,
        offset_m=(7.0, 0.0, 9.0),
    ) -> None:
        super().__init__()
        if not (np.isfinite(frame_period_s) and frame_period_s > 0):
            raise ValueError(f"CameraView: frame_period_s must be > 0, got {frame_period_s!r}")
        if not (8 <= int(thumbnail_px) <= 512):
            raise ValueError(f"CameraView: thumbnail_px must be in [8, 512], got {thumbnail_px}")
        self._meshcat = meshcat
        self._caption = caption
        self._px = int(thumbnail_px)
        self._panel = float(panel_m)
        self._offset = np.asarray(offset_m, dtype=float).reshape(3)
        self._image_port = self.DeclareAbstractInputPort(
            "image", AbstractValue.Make(ImageRgba8U(224, 224))
        )
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._context_port = self.DeclareVectorInputPort("context_id", 1)
        self._features_port = self.DeclareVectorInputPort("features", int(feature_dim))
        self.DeclareInitializationPublishEvent(self._draw_static)
        self.DeclarePeriodicPublishEvent(
            period_sec=frame_period_s, offset_sec=0.0, publish=self._draw
        )
        self._frames: VisibleChoice | None = None
        self._border: VisibleChoice | None = None
        self._context: TextLabel | None = None
        self._caption_label: TextLabel | None = None
        self._n_frames = 0

    @property
    def frames_drawn(self) -> int:
        """Frames put on the panel since the last initialization."""
        return self._n_frames

    def _draw_static(self, context) -> None:
        mc = self._meshcat
        mc.Delete(PATH)
        half = self._panel / 2
        self._n_frames = 0
        self._frames = VisibleChoice(mc, f"{PATH}/frame")
        self._border = VisibleChoice(mc, f"{PATH}/border")
        self._context = TextLabel(mc, f"{PATH}/context", height_m=1.0, max_texts=64)
        mc.SetTransform(f"{PATH}/context", RigidTransform([-half, -0.1, half + 1.2]))
        self._caption_label = TextLabel(mc, f"{PATH}/caption", height_m=0.8, max_texts=128)
        mc.SetTransform(f"{PATH}/caption", RigidTransform([-half, -0.1, -half - 1.0]))

    def _draw(self, context) -> None:
        t = context.get_time()
        mc = self._meshcat
        if not follow_car(mc, PATH, self._state_port.Eval(context), self._offset, t):
            return
        image = self._image_port.Eval(context)
        rgb = np.asarray(image.data)
        if rgb.size and rgb.ndim == 3:

            def frame(path: str) -> None:
                set_image_quad(mc, path, thumbnail(rgb, self._px), self._panel)

            self._frames.show(self._n_frames, t, frame)
            self._n_frames += 1
        if self._context_port.HasValue(context):
            self._draw_context(int(round(float(self._context_port.Eval(context)[0]))), t)
        if self._caption is not None and self._features_port.HasValue(context):
            text = self._caption(np.asarray(self._features_port.Eval(context)))
            self._caption_label.show(text or None, t)

    def _draw_context(self, ctx: int, t: float) -> None:
        mc = self._meshcat
        colour = context_rgb(ctx)

        def border(path: str) -> None:
            side = 1.08 * self._panel
            mc.SetObject(path, Box(side, 0.05, side), Rgba(*colour, 1.0))
            mc.SetTransform(path, RigidTransform([0.0, 0.08, 0.0]))

        self._border.show(ctx, t, border)
        label = f"context {ctx}" if ctx >= 0 else "noise (-1)"
        self._context.show(label, t, rgb=colour if ctx >= 0 else (0.85, 0.85, 0.85))
