"""CameraReceiver: camera frames from LCM (``lcmt_image_array``), checked by a watchdog, as the
station's image."""

from __future__ import annotations

from drake import lcmt_image_array
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, EventStatus, LeafSystem, State
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.hardware.image_messages import ImageMessageError, decode_image_array, image_utime
from pcvfe_drake.hardware.watchdog import StreamLimits, StreamStatus, is_new, require_positive
from pcvfe_drake.systems.texture_camera import to_drake_image


class CameraReceiver(LeafSystem):
    """Decodes the newest camera frame and outputs it while it is fresh, a blank frame otherwise.

    .. pydrake_system::

        name: CameraReceiver
        input_ports:
        - message
        output_ports:
        - image
        - status

    Ports:
        message: input, abstract ``drake.lcmt_image_array`` (Python type, from an
            ``LcmSubscriberSystem``): the first image is the frame (8-bit RGB, RGBA, BGR, BGRA
            or grey; raw, zlib, JPEG or PNG; see ``pcvfe_drake.hardware.image_messages``).
        image: output, abstract ``ImageRgba8U``: the newest accepted frame while it is younger
            than ``timeout_s``; otherwise an all-zero ``width_px`` x ``height_px`` frame, which
            the features turn into NaN and the clustering into noise (-1), so a lost camera
            never feeds a stale view of the ground to the estimator.
        status: output, abstract :class:`pcvfe_drake.hardware.watchdog.StreamStatus` named
            ``"camera"``.

    Rate: a periodic unrestricted update every ``period_s`` decodes a frame it has not seen
    (another timestamp); one that does not decode is rejected as ``malformed``, and the
    watchdog rejects ``out_of_order`` and ``late`` frames (``max_delay_s``; measured on the wall
    clock with ``wall_clock=True``, as on hardware, else on the context time).

    Drake's ``LcmImageArrayToImages`` decodes the same message, but it raises on a malformed
    message (a crash of the loop) and drops the timestamps the watchdog needs; this receiver
    decodes in ``pcvfe_drake.hardware.image_messages`` instead.
    """

    def __init__(
        self,
        *,
        width_px: int,
        height_px: int,
        period_s: float,
        timeout_s: float,
        max_delay_s: float,
        wall_clock: bool = False,
    ) -> None:
        super().__init__()
        require_positive("CameraReceiver", period_s=period_s)
        self.limits = StreamLimits(timeout_s, max_delay_s, wall_clock)
        self._blank = ImageRgba8U(int(width_px), int(height_px))
        self._message_port = self.DeclareAbstractInputPort(
            "message", AbstractValue.Make(lcmt_image_array())
        )
        self._frame_index = self.DeclareAbstractState(AbstractValue.Make(self._blank))
        self._status_index = self.DeclareAbstractState(
            AbstractValue.Make(StreamStatus(name="camera", last_seen_utime=0))
        )
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=period_s, offset_sec=0.0, update=self._check
        )
        self._image_port = self.DeclareAbstractOutputPort(
            "image", lambda: AbstractValue.Make(ImageRgba8U()), self._calc_image
        )
        self._status_port = self.DeclareStateOutputPort("status", self._status_index)

    def _status(self, context: Context) -> StreamStatus:
        return context.get_abstract_state(self._status_index).get_value()

    def _check(self, context: Context, state: State) -> EventStatus:
        t = context.get_time()
        status = self._status(context)
        msg = self._message_port.Eval(context)
        utime = image_utime(msg)
        if is_new(status, utime):
            rgb, problem = None, ""
            try:
                rgb = decode_image_array(msg)
            except ImageMessageError:
                problem = "malformed"
            status, accepted = self.limits.check(status, t, utime, problem)
            if accepted:
                state.get_mutable_abstract_state(self._frame_index).set_value(to_drake_image(rgb))
        status = self.limits.settle(status, t)
        state.get_mutable_abstract_state(self._status_index).set_value(status)
        return EventStatus.Succeeded()

    def _calc_image(self, context: Context, output: AbstractValue) -> None:
        if self.limits.condition(self._status(context), context.get_time()) == "ok":
            output.set_value(context.get_abstract_state(self._frame_index).get_value())
        else:
            output.set_value(self._blank)
