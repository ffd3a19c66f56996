"""CameraReceiver: every camera frame from LCM (``lcmt_image_array``), checked by a watchdog and
handed out at its own time, as the station's image."""

from __future__ import annotations

import struct
import time
from collections.abc import Callable

from drake import lcmt_image_array
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, EventStatus, LeafSystem, State
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.hardware.image_messages import ImageMessageError, decode_image_array, image_utime
from pcvfe_drake.hardware.playout import MessageQueue, Playout, PlayoutLimits, drain_and_check
from pcvfe_drake.hardware.watchdog import StreamStatus, require_positive
from pcvfe_drake.systems.texture_camera import to_drake_image


def decode_frame(data: bytes):
    """``(utime, rgb, problem)`` of an encoded ``lcmt_image_array`` (problem ``"malformed"``
    when it does not decode, else ``""``)."""
    try:
        msg = lcmt_image_array.decode(data)
    except (ValueError, struct.error):
        return 0, None, "malformed"
    utime = image_utime(msg)
    try:
        return utime, decode_image_array(msg), ""
    except ImageMessageError:
        return utime, None, "malformed"


class CameraReceiver(LeafSystem):
    """Decodes every camera frame and outputs the current one while it is fresh, a blank frame
    otherwise.

    .. pydrake_system::

        name: CameraReceiver
        output_ports:
        - image
        - status

    No input port (as Drake's ``LcmSubscriberSystem``): the frames come from a
    :class:`pcvfe_drake.hardware.playout.MessageQueue` that the station's LCM subscription
    fills (8-bit RGB, RGBA, BGR, BGRA or grey; raw, zlib, JPEG or PNG; see
    ``pcvfe_drake.hardware.image_messages``).

    Ports:
        image: output, abstract ``ImageRgba8U``: the frame handed out last while that was at
            most ``timeout_s`` ago; otherwise an all-zero ``width_px`` x ``height_px`` frame,
            which the features turn into NaN and the clustering into noise (-1), so a lost
            camera never feeds a stale view of the ground to the estimator.
        status: output, abstract :class:`pcvfe_drake.hardware.watchdog.StreamStatus` named
            ``"camera"``.

    Rate: a periodic unrestricted update every ``period_s`` drains the queue, decodes every
    frame (one that does not decode is rejected as ``malformed``; the watchdog rejects
    ``duplicate``, ``out_of_order`` and ``late`` frames, ``max_delay_s`` on the wall clock with
    ``wall_clock=True``, as on hardware, else on the context time) and hands out the newest frame
    due at the context time (:mod:`pcvfe_drake.hardware.playout`; held back up to
    ``max_hold_s``, default 0: the newest). ``pump(timeout_ms)``, when
    given (the bus's ``DrakeLcm.HandleSubscriptions``), is called with 0 before each drain.

    Drake's ``LcmImageArrayToImages`` decodes the same message, but it raises on a malformed
    message (a crash of the loop) and drops the timestamps the watchdog needs; this receiver
    decodes in ``pcvfe_drake.hardware.image_messages`` instead.
    """

    def __init__(
        self,
        *,
        queue: MessageQueue,
        width_px: int,
        height_px: int,
        period_s: float,
        timeout_s: float,
        max_delay_s: float,
        wall_clock: bool = False,
        rate: float = 1.0,
        max_hold_s: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
        pump: Callable[[int], int] | None = None,
    ) -> None:
        super().__init__()
        require_positive("CameraReceiver", period_s=period_s)
        self.limits = PlayoutLimits(
            timeout_s=timeout_s,
            max_delay_s=max_delay_s,
            wall_clock=wall_clock,
            rate=rate,
            max_hold_s=max_hold_s,
        )
        self._queue = queue
        self._clock = clock
        self._pump = pump
        self._blank = ImageRgba8U(int(width_px), int(height_px))
        self._frame_index = self.DeclareAbstractState(AbstractValue.Make(self._blank))
        self._playout_index = self.DeclareAbstractState(
            AbstractValue.Make(Playout(StreamStatus(name="camera")))
        )
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=period_s, offset_sec=0.0, update=self._check
        )
        self._image_port = self.DeclareAbstractOutputPort(
            "image",
            lambda: AbstractValue.Make(ImageRgba8U()),
            self._calc_image,
            prerequisites_of_calc={self.all_state_ticket(), self.time_ticket()},
        )
        self._status_port = self.DeclareAbstractOutputPort(
            "status",
            lambda: AbstractValue.Make(StreamStatus()),
            self._calc_status,
            prerequisites_of_calc={self.abstract_state_ticket(self._playout_index)},
        )

    def _playout(self, context: Context) -> Playout:
        return context.get_abstract_state(self._playout_index).get_value()

    def _check(self, context: Context, state: State) -> EventStatus:
        if self._pump is not None:
            self._pump(0)
        wall = self._clock() if self.limits.wall_clock else None
        playout, out = drain_and_check(
            self._queue, decode_frame, self._playout(context), context.get_time(), wall, self.limits
        )
        if out is not None:
            state.get_mutable_abstract_state(self._frame_index).set_value(
                to_drake_image(out.payload)
            )
        state.get_mutable_abstract_state(self._playout_index).set_value(playout)
        return EventStatus.Succeeded()

    def _calc_image(self, context: Context, output: AbstractValue) -> None:
        if self.limits.condition(self._playout(context).status, context.get_time()) == "ok":
            output.set_value(context.get_abstract_state(self._frame_index).get_value())
        else:
            output.set_value(self._blank)

    def _calc_status(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self._playout(context).status)
