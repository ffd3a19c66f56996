"""VehicleStateReceiver: the vehicle's LCM state messages, checked by a watchdog, as a state
vector."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, Context, EventStatus, LeafSystem, State

from pcvfe_drake.hardware.watchdog import StreamLimits, StreamStatus, is_new, require_positive
from pcvfe_drake.lcmtypes import lcmt_vehicle_state
from pcvfe_drake.vehicle.single_track import NX


class VehicleStateReceiver(LeafSystem):
    """Turns the latest ``lcmt_vehicle_state`` into the station's ``state``, or NaN.

    .. pydrake_system::

        name: VehicleStateReceiver
        input_ports:
        - message
        output_ports:
        - state
        - state_utime
        - status

    Ports:
        message: input, abstract ``pcvfe_drake.lcmtypes.lcmt_vehicle_state`` (from an
            ``LcmSubscriberSystem``, which holds the newest message received).
        state: output (7) ``[sx m, sy m, delta rad, v m/s, psi rad, psi_dot rad/s, beta rad]``:
            the newest accepted message's state while it is younger than ``timeout_s``, else
            all NaN (the NMPC's fallback: its last plan shifted, then braking).
        state_utime: output (1), the newest accepted message's ``utime`` [us] (-1: none).
        status: output, abstract :class:`pcvfe_drake.hardware.watchdog.StreamStatus` named
            ``"state"`` (counts of accepted and rejected messages by reason).

    Rate: a periodic unrestricted update every ``period_s`` looks at the input; a message it has
    not seen (another ``utime``) is checked by :func:`pcvfe_drake.hardware.watchdog.check_message`
    (non-finite, invalid, out of order, late by more than ``max_delay_s``; the delay on the
    wall clock with ``wall_clock=True``, as on hardware, else on the context time). A default
    message
    (``utime`` 0, what the subscriber holds before the first message) is never taken.
    """

    def __init__(
        self, *, period_s: float, timeout_s: float, max_delay_s: float, wall_clock: bool = False
    ) -> None:
        super().__init__()
        require_positive("VehicleStateReceiver", period_s=period_s)
        self.limits = StreamLimits(timeout_s, max_delay_s, wall_clock)
        self._message_port = self.DeclareAbstractInputPort(
            "message", AbstractValue.Make(lcmt_vehicle_state())
        )
        self._state_index = self.DeclareDiscreteState(np.full(NX + 1, np.nan))
        self._status_index = self.DeclareAbstractState(
            AbstractValue.Make(StreamStatus(name="state", last_seen_utime=0))
        )
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=period_s, offset_sec=0.0, update=self._check
        )
        self._out_state = self.DeclareVectorOutputPort("state", NX, self._calc_state)
        self._out_utime = self.DeclareVectorOutputPort(
            "state_utime",
            1,
            self._calc_utime,
            prerequisites_of_calc={self.discrete_state_ticket(self._state_index)},
        )
        self._out_status = self.DeclareStateOutputPort("status", self._status_index)

    def _status(self, context: Context) -> StreamStatus:
        return context.get_abstract_state(self._status_index).get_value()

    def _check(self, context: Context, state: State) -> EventStatus:
        t = context.get_time()
        status = self._status(context)
        msg = self._message_port.Eval(context)
        if is_new(status, msg.utime):
            x = np.asarray(msg.state, dtype=float)
            problem = ""
            if x.shape != (NX,) or not np.all(np.isfinite(x)):
                problem = "non_finite"
            elif not msg.valid:
                problem = "invalid"
            status, accepted = self.limits.check(status, t, msg.utime, problem)
            if accepted:
                state.get_mutable_discrete_state(self._state_index).set_value(
                    np.concatenate([x, [float(msg.utime)]])
                )
        status = self.limits.settle(status, t)
        state.get_mutable_abstract_state(self._status_index).set_value(status)
        return EventStatus.Succeeded()

    def _calc_state(self, context: Context, output: BasicVector) -> None:
        status = self._status(context)
        if self.limits.condition(status, context.get_time()) == "ok":
            output.SetFromVector(context.get_discrete_state(self._state_index).value()[:NX])
        else:
            output.SetFromVector(np.full(NX, np.nan))

    def _calc_utime(self, context: Context, output: BasicVector) -> None:
        utime = context.get_discrete_state(self._state_index).value()[NX]
        output.SetFromVector([utime if np.isfinite(utime) else -1.0])
