"""DriveLogPlayer: a recorded drive played out of the station's ports (the replay station)."""

from __future__ import annotations

from functools import lru_cache

import cv2
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, Context, LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.hardware.replay import ReplayLog
from pcvfe_drake.systems.texture_camera import to_drake_image
from pcvfe_drake.vehicle.single_track import NU, NX

FRAME_CACHE = 64
"""Decoded frames kept in memory (frames are read from disk as the replay reaches them)."""


class DriveLogPlayer(LeafSystem):
    """Plays a :class:`pcvfe_drake.hardware.replay.ReplayLog` as functions of time.

    .. pydrake_system::

        name: DriveLogPlayer
        input_ports:
        - actuation
        output_ports:
        - state
        - logged_actuation
        - image
        - true_mu
        - true_terrain
        - true_state
        - features

    Ports:
        actuation: input (2), accepted and not used: a recorded drive cannot be steered.
        state: output (7), the logged ST state of the newest row at or before the context time
            (zero-order hold; exact at the rows' times).
        logged_actuation: output (2) ``[steer_rate rad/s, accel m/s^2]``, the input recorded as
            applied just before the context time (what a controller's held output reads then).
        image: output, abstract ``ImageRgba8U``: the newest frame captured before the context
            time (``ReplayLog.frame_at``; blank before the first).
        true_mu, true_terrain: outputs (1) only when the log has truth (``mu_true``).
        true_state: output (7) only when the log has the true state (``true_*`` columns).
        features: output (D) only with ``logged_features``: the features the run computed
            from the newest frame captured before the context time (``ReplayLog.features_at``).

    Pure output calcs of the context time (no state, no events). Frames are read from disk
    when first needed and the last ``FRAME_CACHE`` kept (a memo of files, not simulation state).
    """

    def __init__(
        self,
        log: ReplayLog,
        *,
        width_px: int = 224,
        height_px: int = 224,
        logged_features: bool = False,
    ) -> None:
        super().__init__()
        self.log = log
        self._blank = ImageRgba8U(int(width_px), int(height_px))
        self.DeclareVectorInputPort("actuation", NU)
        self.DeclareVectorOutputPort("state", NX, self._calc_state)
        self.DeclareVectorOutputPort("logged_actuation", NU, self._calc_actuation)
        self.DeclareAbstractOutputPort(
            "image", lambda: AbstractValue.Make(ImageRgba8U()), self._calc_image
        )
        if log.has_truth:
            self.DeclareVectorOutputPort("true_mu", 1, self._calc_true_mu)
            self.DeclareVectorOutputPort("true_terrain", 1, self._calc_true_terrain)
        if log.true_states is not None:
            self.DeclareVectorOutputPort("true_state", NX, self._calc_true_state)
        if logged_features:
            if log.features is None:
                raise ValueError(f"DriveLogPlayer: {log.source} holds no logged features")
            self.DeclareVectorOutputPort("features", log.features.shape[1], self._calc_features)
        self._load = lru_cache(maxsize=FRAME_CACHE)(self._read_frame)

    def _read_frame(self, index: int) -> ImageRgba8U:
        path = self.log.frame_paths[index]
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"DriveLogPlayer: camera frame {path} cannot be read")
        return to_drake_image(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))

    def _calc_state(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.log.state_at(context.get_time()))

    def _calc_actuation(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.log.actuation_before(context.get_time()))

    def _calc_image(self, context: Context, output: AbstractValue) -> None:
        k = self.log.frame_at(context.get_time())
        output.set_value(self._load(k) if k >= 0 else self._blank)

    def _calc_true_mu(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector([self.log.truth_at(context.get_time())[0]])

    def _calc_true_state(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.log.true_state_at(context.get_time()))

    def _calc_true_terrain(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector([self.log.truth_at(context.get_time())[1]])

    def _calc_features(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.log.features_at(context.get_time()))
