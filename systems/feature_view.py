"""FeatureView: the clustering's feature space in Meshcat, under ``/pcvfe/features``."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Meshcat, Rgba, Sphere
from pydrake.math import RigidTransform
from pydrake.perception import BaseField, Fields, PointCloud
from pydrake.systems.framework import LeafSystem

from pcvfe_drake.contexts.clustering import ClusterTable, StoredFeatures
from pcvfe_drake.runs.palette import context_rgb, context_rgb_array
from pcvfe_drake.systems.meshcat_layer import ROOT, VisibleChoice, set_image_quad
from pcvfe_drake.views.feature_projection import PcaProjection, centroids
from pcvfe_drake.views.labels import text_image

PATH = f"{ROOT}/features"
NOISE_GREY = (0.55, 0.55, 0.55)


class FeatureView(LeafSystem):
    """The stored feature vectors projected to 3-D, coloured by context, beside the course.

    At each re-clustering (a new ``cluster_table.n_reclusterings``) a PCA is fitted to the
    stored vectors (:class:`pcvfe_drake.views.feature_projection.PcaProjection`) and the store
    is drawn as one point cloud ``/pcvfe/features/clouds/<k>`` (contexts in their colours, noise
    grey) with each context's id as text at its centroid; the cloud of the previous
    re-clustering is hidden from then on. Every publish, the current frame's vector is projected
    with the current fit: ``/pcvfe/features/current``, a large sphere in its context's colour
    inside a translucent white one. Nothing is drawn before the first re-clustering (there is no
    fit yet). The cloud spans about ``size_m`` around ``origin_m``.

    .. pydrake_system::

        name: FeatureView
        input_ports:
        - features
        - context_id
        - cluster_table
        - stored_features

    Rate: one periodic publish every ``period_s`` (default 0.1 s).
    """

    def __init__(
        self,
        meshcat: Meshcat,
        feature_dim: int,
        *,
        origin_m=(0.0, 0.0, 15.0),
        size_m: float = 30.0,
        period_s: float = 0.1,
        point_size_m: float = 1.0,
    ) -> None:
        super().__init__()
        if not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"FeatureView: period_s must be > 0, got {period_s!r}")
        if not (np.isfinite(size_m) and size_m > 0):
            raise ValueError(f"FeatureView: size_m must be > 0, got {size_m!r}")
        self._meshcat = meshcat
        self._origin = np.asarray(origin_m, dtype=float).reshape(3)
        self._size = float(size_m)
        self._point_size = float(point_size_m)
        self._features_port = self.DeclareVectorInputPort("features", int(feature_dim))
        self._context_port = self.DeclareVectorInputPort("context_id", 1)
        self._table_port = self.DeclareAbstractInputPort(
            "cluster_table", AbstractValue.Make(ClusterTable())
        )
        self._stored_port = self.DeclareAbstractInputPort(
            "stored_features", AbstractValue.Make(StoredFeatures())
        )
        self.DeclareInitializationPublishEvent(self._draw_static)
        self.DeclarePeriodicPublishEvent(period_sec=period_s, offset_sec=0.0, publish=self._draw)
        self._clouds: VisibleChoice | None = None
        self._current: VisibleChoice | None = None
        self._fit: PcaProjection | None = None
        self._fitted_at = 0

    @property
    def projection(self) -> PcaProjection | None:
        """The fit in use (None before the first re-clustering)."""
        return self._fit

    def _draw_static(self, context) -> None:
        mc = self._meshcat
        mc.Delete(PATH)
        self._fit = None
        self._fitted_at = 0
        self._clouds = VisibleChoice(mc, f"{PATH}/clouds")
        self._current = VisibleChoice(mc, f"{PATH}/current")
        mc.SetObject(f"{PATH}/current/halo", Sphere(1.4), Rgba(1.0, 1.0, 1.0, 0.35))
        mc.SetProperty(f"{PATH}/current/halo", "visible", False, 0.0)

    def _draw(self, context) -> None:
        t = context.get_time()
        table: ClusterTable = self._table_port.Eval(context)
        if table.n_reclusterings > self._fitted_at:
            self._refit(self._stored_port.Eval(context), t)
            self._fitted_at = table.n_reclusterings
        if self._fit is None:
            return
        z = np.asarray(self._features_port.Eval(context), dtype=float)
        mc = self._meshcat
        if not np.all(np.isfinite(z)):
            self._current.show(None, t)
            mc.SetProperty(f"{PATH}/current/halo", "visible", False, t)
            return
        p = self._fit.project(z)
        mc.SetTransform(f"{PATH}/current", RigidTransform(p), t)
        mc.SetProperty(f"{PATH}/current/halo", "visible", True, t)
        ctx = int(round(float(self._context_port.Eval(context)[0])))
        rgb = context_rgb(ctx) if ctx >= 0 else NOISE_GREY

        def create(path: str) -> None:
            mc.SetObject(path, Sphere(0.8), Rgba(*rgb, 1.0))

        self._current.show(ctx, t, create)

    def _refit(self, stored: StoredFeatures, t: float) -> None:
        z = np.asarray(stored.z, dtype=float)
        if z.ndim != 2 or len(z) < 2:
            return
        self._fit = PcaProjection.fit(z, size_m=self._size, origin_m=self._origin)
        points = self._fit.project(z)
        labels = np.asarray(stored.labels).astype(int)
        mc = self._meshcat

        def create(path: str) -> None:
            cloud = PointCloud(len(points), Fields(BaseField.kXYZs | BaseField.kRGBs))
            cloud.mutable_xyzs()[:] = points.T
            rgb = context_rgb_array(labels)
            rgb[labels < 0] = NOISE_GREY
            cloud.mutable_rgbs()[:] = np.round(255 * rgb.T).astype(np.uint8)
            mc.SetObject(f"{path}/points", cloud, point_size=self._point_size)
            for k, c in centroids(points, labels).items():
                image = text_image(str(k), rgb=context_rgb(k), height_px=48)
                label = f"{path}/ids/{k}"
                set_image_quad(mc, label, image, 1.6 * image.shape[1] / image.shape[0])
                mc.SetTransform(label, RigidTransform(c + [0.0, -1.0, 1.5]))

        self._clouds.show(stored.n_reclusterings, t, create)
