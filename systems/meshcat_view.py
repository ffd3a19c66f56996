"""MeshcatView: the PC-VFE run drawn in Meshcat (ground texture, car, paths, friction gauge)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np
from pydrake.geometry import Box, Mesh, Meshcat, Rgba
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.perception import BaseField, Fields, PointCloud
from pydrake.systems.framework import LeafSystem

from pcvfe_drake.perception.ground_render import render_topdown
from pcvfe_drake.perception.terrain import TerrainMap
from pcvfe_drake.runs.palette import context_rgb, context_rgb_array
from pcvfe_drake.vehicle.single_track import NX, PSI, SX, SY

ROOT = "/pcvfe"


class MeshcatView(LeafSystem):
    """Draws the closed loop in Meshcat and records it when Meshcat is recording.

    Static scene (drawn at initialization): the ground as a textured quad (the terrain map's
    top-down render, or ``ground_image``, an (H, W, 3) RGB image of the map's rectangle with row 0
    at the northern edge; z = 0), the reference path (white line). Animated at ``period_s``: the car
    (a box of the vehicle's length and width at its pose), the driven path as dots coloured by
    the discovered context (noise black, as the paper's Fig. 4; published in chunks of
    ``trail_chunk_s`` that appear at their time in the recording), a roof marker in the current
    context's colour, and a friction gauge riding on the car: an orange bar of height
    ``bar_m_per_mu * mu_hat`` beside a translucent blue bar of the true mu (sim-only), the colours
    of the paper's Fig. 5.

    Every call passes the simulation time as ``time_in_recording``, so ``meshcat.StartRecording()``
    before ``AdvanceTo`` and ``PublishRecording()`` after give a replayable animation, and
    ``meshcat.StaticHtml()`` a standalone playback file. The trail buffer is visualisation output
    only (it never feeds back into the simulation) and is reset by the initialization event.

    .. pydrake_system::

        name: MeshcatView
        input_ports:
        - state
        - context_id
        - theta_hat
        - true_mu

    ``true_mu`` is the station's sim-only truth: leave it unconnected where the station has none.

    Rate: one periodic publish event every ``period_s`` (default 0.1 s, 10 Hz).
    """

    def __init__(
        self,
        meshcat: Meshcat,
        terrain_map: TerrainMap,
        reference_xy: np.ndarray,
        *,
        vehicle_length_m: float = 4.3,
        vehicle_width_m: float = 1.7,
        period_s: float = 0.1,
        trail_chunk_s: float = 1.0,
        ground_px_per_m: float = 4.0,
        bar_m_per_mu: float = 5.0,
        ground_image: np.ndarray | None = None,
    ) -> None:
        super().__init__()
        if not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"MeshcatView: period_s must be > 0, got {period_s!r}")
        ref = np.asarray(reference_xy, dtype=float)
        if ref.ndim != 2 or ref.shape[1] != 2 or len(ref) < 2 or not np.all(np.isfinite(ref)):
            raise ValueError(f"MeshcatView: reference_xy must be finite (N>=2, 2), got {ref.shape}")
        self._meshcat = meshcat
        self._terrain_map = terrain_map
        self._reference_xy = ref
        self._length = float(vehicle_length_m)
        self._width = float(vehicle_width_m)
        self._ground_px_per_m = float(ground_px_per_m)
        self._ground_image = ground_image
        self._bar_m_per_mu = float(bar_m_per_mu)
        self._chunk_len = max(1, int(round(trail_chunk_s / period_s)))
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._context_port = self.DeclareVectorInputPort("context_id", 1)
        self._theta_port = self.DeclareVectorInputPort("theta_hat", 3)
        self._true_mu_port = self.DeclareVectorInputPort("true_mu", 1)
        self.DeclareInitializationPublishEvent(self._draw_static)
        self.DeclarePeriodicPublishEvent(period_sec=period_s, offset_sec=0.0, publish=self._draw)
        self._trail: list[tuple[float, float, int]] = []
        self._chunks = 0
        self._markers: set[int] = set()
        self._shown_context: int | None = None

    # ------------------------------------------------------------------ static scene
    def _draw_static(self, context) -> None:
        mc = self._meshcat
        for part in ("ground", "reference", "car", "driven"):
            mc.Delete(f"{ROOT}/{part}")
        self._trail = []
        self._chunks = 0
        self._markers = set()
        self._shown_context = None
        self._draw_ground()
        ref = self._reference_xy
        closed = np.vstack([ref, ref[:1]]) if np.linalg.norm(ref[0] - ref[-1]) > 1e-6 else ref
        line = np.vstack([closed.T, np.full(len(closed), 0.05)])
        mc.SetLine(f"{ROOT}/reference", np.asfortranarray(line), 3.0, Rgba(1, 1, 1, 1))
        mc.SetObject(
            f"{ROOT}/car/body",
            Box(self._length, self._width, 1.4),
            Rgba(0.85, 0.85, 0.9, 1),
        )
        mc.SetTransform(f"{ROOT}/car/body", RigidTransform([0.0, 0.0, 0.7]))
        bar = 0.5
        mc.SetObject(f"{ROOT}/car/mu_hat", Box(bar, bar, 1.0), Rgba(1.0, 0.5, 0.05, 1))
        mc.SetObject(f"{ROOT}/car/mu_true", Box(bar, bar, 1.0), Rgba(0.12, 0.47, 0.71, 0.4))
        x0, x1, y0, y1 = self._terrain_map.bounds_m
        span = max(x1 - x0, y1 - y0)
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
        # Meshcat's default far plane (100 m) would clip a course-sized scene.
        mc.SetCamera(Meshcat.PerspectiveCamera(fov=50.0, near=0.5, far=20.0 * span))
        mc.SetCameraPose(centre + np.array([0.0, -0.6 * span, 0.6 * span]), centre)
        mc.SetProperty("/Grid", "visible", False)
        # Flat, bright lighting so the ground shows the texture's own colours (the default point
        # lights leave a hot spot at the origin and darken the rest of a course-sized scene).
        mc.SetProperty("/Lights/AmbientLight/<object>", "intensity", 2.2)
        mc.SetProperty("/Lights/PointLightNegativeX", "visible", False)
        mc.SetProperty("/Lights/PointLightPositiveX", "visible", False)

    def _draw_ground(self) -> None:
        image = self._ground_image
        if image is None:
            image = render_topdown(self._terrain_map, self._ground_px_per_m)
        image = np.ascontiguousarray(image, dtype=np.uint8)
        if image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"MeshcatView: ground image must be (H, W, 3) RGB, got {image.shape}")
        x0, x1, y0, y1 = self._terrain_map.bounds_m
        with tempfile.TemporaryDirectory(prefix="pcvfe_ground_") as tmp:
            folder = Path(tmp)
            cv2.imwrite(str(folder / "ground.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            (folder / "ground.mtl").write_text(
                "newmtl ground\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd ground.png\n"
            )
            # Image row 0 is the northern edge: texture v = 1 at y_max.
            (folder / "ground.obj").write_text(
                "mtllib ground.mtl\n"
                f"v {x0} {y0} 0\nv {x1} {y0} 0\nv {x1} {y1} 0\nv {x0} {y1} 0\n"
                "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nusemtl ground\n"
                "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n"
            )
            self._meshcat.SetObject(f"{ROOT}/ground", Mesh(str(folder / "ground.obj")))

    # ------------------------------------------------------------------ animation
    def _draw(self, context) -> None:
        t = context.get_time()
        x = self._state_port.Eval(context)
        if not np.all(np.isfinite(x[[SX, SY, PSI]])):
            return
        ctx = int(round(float(self._context_port.Eval(context)[0])))
        mu_hat = float(self._theta_port.Eval(context)[0])
        # Sim-only truth: unconnected on a hardware or replay station (no bar drawn).
        mu_true = (
            float(self._true_mu_port.Eval(context)[0])
            if self._true_mu_port.HasValue(context)
            else float("nan")
        )
        mc = self._meshcat
        pose = RigidTransform(RotationMatrix.MakeZRotation(float(x[PSI])), [x[SX], x[SY], 0.0])
        mc.SetTransform(f"{ROOT}/car", pose, t)
        if ctx != self._shown_context:
            self._show_context_marker(ctx, t)
        self._set_bar("mu_hat", mu_hat, -0.35, t)
        self._set_bar("mu_true", mu_true, 0.35, t)
        self._trail.append((float(x[SX]), float(x[SY]), ctx))
        if len(self._trail) >= self._chunk_len:
            self._flush_trail(t)

    def _show_context_marker(self, ctx: int, t: float) -> None:
        """Show the roof marker of context ``ctx`` (created on first use), hide the previous one.

        Meshcat animations cannot key a colour, so each context has its own marker object and
        the recording keys their visibility.
        """
        mc = self._meshcat
        path = f"{ROOT}/car/context/{ctx}"
        if ctx not in self._markers:
            r, g, b = context_rgb(ctx)
            marker = Box(0.6 * self._length, 0.9 * self._width, 0.1)
            mc.SetObject(path, marker, Rgba(r, g, b, 1.0))
            mc.SetTransform(path, RigidTransform([0.0, 0.0, 1.45]))
            mc.SetProperty(path, "visible", False, 0.0)
            self._markers.add(ctx)
        if self._shown_context is not None:
            mc.SetProperty(f"{ROOT}/car/context/{self._shown_context}", "visible", False, t)
        mc.SetProperty(path, "visible", True, t)
        self._shown_context = ctx

    def _set_bar(self, name: str, mu: float, y_offset_m: float, t: float) -> None:
        height = max(1e-3, self._bar_m_per_mu * mu) if np.isfinite(mu) else 1e-3
        path = f"{ROOT}/car/{name}"
        self._meshcat.SetTransform(path, RigidTransform([0.0, y_offset_m, 1.4 + height / 2]), t)
        self._meshcat.SetProperty(path, "scale", [1.0, 1.0, height], t)

    def _flush_trail(self, t: float) -> None:
        pts = np.array(self._trail)
        self._trail = []
        cloud = PointCloud(len(pts), Fields(BaseField.kXYZs | BaseField.kRGBs))
        cloud.mutable_xyzs()[:] = np.vstack([pts[:, 0], pts[:, 1], np.full(len(pts), 0.15)])
        rgb = context_rgb_array(pts[:, 2])
        cloud.mutable_rgbs()[:] = np.round(255 * rgb.T).astype(np.uint8)
        path = f"{ROOT}/driven/{self._chunks:05d}"
        self._chunks += 1
        self._meshcat.SetObject(path, cloud, point_size=0.8)
        self._meshcat.SetProperty(path, "visible", False, 0.0)
        self._meshcat.SetProperty(path, "visible", True, t)

    def flush(self, context) -> None:
        """Draw what is left of the trail (call once after the last AdvanceTo)."""
        if self._trail:
            self._flush_trail(context.get_time())
