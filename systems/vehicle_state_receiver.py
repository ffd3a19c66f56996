"""VehicleStateReceiver: every LCM state message of the vehicle, checked by a watchdog and handed
out at its own time, as a state vector."""

from __future__ import annotations

import struct
import time
from collections.abc import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, Context, EventStatus, LeafSystem, State

from pcvfe_drake.hardware.playout import MessageQueue, Playout, PlayoutLimits, drain_and_check
from pcvfe_drake.hardware.watchdog import StreamStatus, require_positive
from pcvfe_drake.lcmtypes import lcmt_vehicle_state
from pcvfe_drake.vehicle.single_track import NX


def decode_state(data: bytes) -> tuple[int, np.ndarray | None, str]:
    """``(utime, state, problem)`` of an encoded ``lcmt_vehicle_state`` (problem: a watchdog
    rejection reason or ``""``)."""
    try:
        msg = lcmt_vehicle_state.decode(data)
    except (ValueError, struct.error):  # another type's fingerprint, or cut short
        return 0, None, "malformed"
    x = np.asarray(msg.state, dtype=float)
    if x.shape != (NX,) or not np.all(np.isfinite(x)):
        return msg.utime, None, "non_finite"
    if not msg.valid:
        return msg.utime, None, "invalid"
    return msg.utime, x, ""


class VehicleStateReceiver(LeafSystem):
    """Turns the vehicle's ``lcmt_vehicle_state`` messages into the station's ``state``, or NaN.

    .. pydrake_system::

        name: VehicleStateReceiver
        output_ports:
        - state
        - state_utime
        - status

    Like Drake's ``LcmSubscriberSystem`` it has no input port: its messages come from a
    :class:`pcvfe_drake.hardware.playout.MessageQueue` that an LCM subscription fills (the
    hardware station subscribes it: ``lcm.Subscribe(channel, queue.push)``), and events move
    them into the context. Unlike that system it keeps every message, not only the newest.

    Ports:
        state: output (7) ``[sx m, sy m, delta rad, v m/s, psi rad, psi_dot rad/s, beta rad]``:
            the message handed out last while that was at most ``timeout_s`` ago, else all NaN
            (the NMPC's fallback: its last plan shifted, then braking).
        state_utime: output (1), that message's ``utime`` [us] (-1: none yet).
        status: output, abstract :class:`pcvfe_drake.hardware.watchdog.StreamStatus` named
            ``"state"`` (counts of accepted, handed out, superseded and rejected messages by
            reason; the station's lag behind the wall clock).

    Rate: a periodic unrestricted update every ``period_s`` drains the queue, checks every
    message in arrival order (malformed, non-finite, invalid, duplicate, out of order, late by
    more than ``max_delay_s``; delays on the wall clock with ``wall_clock=True``, as on
    hardware, else on the context time) and hands out the newest message that is due at the
    context time (:mod:`pcvfe_drake.hardware.playout`). With ``max_hold_s`` 0 (the default)
    that is the newest message; with more, a station catching up on wall time after a stall
    sees each message at its own tick, holding messages back up to ``max_hold_s``. The
    timeout counts on the wall clock as the station maps it: the late ticks of a stall, run
    at one wall instant, do not age the data.

    ``pump(timeout_ms)`` (e.g. the bus's ``DrakeLcm.HandleSubscriptions``), when given, is
    called with 0 at each check before the queue is drained, so a message that arrived while
    the simulator slept to keep pace is taken at once. With ``first_message_timeout_s`` > 0 an
    initialization event waits (wall clock, pumping) until the queue holds a message, raises
    naming ``source`` if none comes, and checks and hands out what came, so that the state is
    there for the controller's first update (periodic updates at the start time all see the
    state before any of them).
    """

    def __init__(
        self,
        *,
        queue: MessageQueue,
        period_s: float,
        timeout_s: float,
        max_delay_s: float,
        wall_clock: bool = False,
        rate: float = 1.0,
        max_hold_s: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
        first_message_timeout_s: float = 0.0,
        pump: Callable[[int], int] | None = None,
        source: str = "the state channel",
    ) -> None:
        super().__init__()
        require_positive("VehicleStateReceiver", period_s=period_s)
        self.limits = PlayoutLimits(
            timeout_s=timeout_s,
            max_delay_s=max_delay_s,
            wall_clock=wall_clock,
            rate=rate,
            max_hold_s=max_hold_s,
        )
        self._queue = queue
        self._clock = clock
        self._first_message_timeout_s = float(first_message_timeout_s)
        self._pump = pump
        self._source = source
        self._state_index = self.DeclareDiscreteState(np.full(NX + 1, np.nan))
        self._playout_index = self.DeclareAbstractState(
            AbstractValue.Make(Playout(StreamStatus(name="state")))
        )
        if self._first_message_timeout_s > 0:
            self.DeclareInitializationUnrestrictedUpdateEvent(self._wait_for_first_message)
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=period_s, offset_sec=0.0, update=self._check
        )
        self._out_state = self.DeclareVectorOutputPort(
            "state",
            NX,
            self._calc_state,
            prerequisites_of_calc={self.all_state_ticket(), self.time_ticket()},
        )
        self._out_utime = self.DeclareVectorOutputPort(
            "state_utime",
            1,
            self._calc_utime,
            prerequisites_of_calc={self.discrete_state_ticket(self._state_index)},
        )
        self._out_status = self.DeclareAbstractOutputPort(
            "status",
            lambda: AbstractValue.Make(StreamStatus()),
            self._calc_status,
            prerequisites_of_calc={self.abstract_state_ticket(self._playout_index)},
        )

    def _playout(self, context: Context) -> Playout:
        return context.get_abstract_state(self._playout_index).get_value()

    def _wait_for_first_message(self, context: Context, state: State) -> EventStatus:
        deadline = time.monotonic() + self._first_message_timeout_s
        while not len(self._queue) and time.monotonic() < deadline:
            if self._pump is None:
                time.sleep(0.01)
            else:
                self._pump(10)
        if not len(self._queue):
            raise RuntimeError(
                f"VehicleStateReceiver: no state message on {self._source} within "
                f"{self._first_message_timeout_s} s (hardware.first_message_timeout_s); is the "
                "vehicle (or `pcvfe vehicle-bridge`) running on that URL?"
            )
        # Hand it out now: the controller's first update, at the same time as the first
        # periodic check, would otherwise see no state and brake a car it has not seen.
        return self._check(context, state)

    def _check(self, context: Context, state: State) -> EventStatus:
        if self._pump is not None:
            self._pump(0)  # what has arrived since the last step, not only up to it
        wall = self._clock() if self.limits.wall_clock else None
        playout, out = drain_and_check(
            self._queue, decode_state, self._playout(context), context.get_time(), wall, self.limits
        )
        if out is not None:
            state.get_mutable_discrete_state(self._state_index).set_value(
                np.concatenate([out.payload, [float(out.utime)]])
            )
        state.get_mutable_abstract_state(self._playout_index).set_value(playout)
        return EventStatus.Succeeded()

    def _calc_state(self, context: Context, output: BasicVector) -> None:
        status = self._playout(context).status
        if self.limits.condition(status, context.get_time()) == "ok":
            output.SetFromVector(context.get_discrete_state(self._state_index).value()[:NX])
        else:
            output.SetFromVector(np.full(NX, np.nan))

    def _calc_utime(self, context: Context, output: BasicVector) -> None:
        utime = context.get_discrete_state(self._state_index).value()[NX]
        output.SetFromVector([utime if np.isfinite(utime) else -1.0])

    def _calc_status(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self._playout(context).status)
