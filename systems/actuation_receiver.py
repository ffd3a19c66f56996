"""ActuationReceiver: the controller's LCM commands on the vehicle side, braking when they stop."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, Context, EventStatus, LeafSystem, State

from pcvfe_drake.hardware.watchdog import StreamLimits, StreamStatus, is_new, require_positive
from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation
from pcvfe_drake.vehicle.single_track import NU, NX, V

BRAKE_BLEND_MPS = 0.5
"""Below this speed any braking (a negative acceleration, commanded or the watchdog's) fades
linearly to zero: a brake stops the car, it does not drive it backwards."""


class ActuationReceiver(LeafSystem):
    """What the vehicle applies: the newest accepted command, or braking when commands stop.

    .. pydrake_system::

        name: ActuationReceiver
        input_ports:
        - message
        - state
        output_ports:
        - actuation
        - status

    Ports:
        message: input, abstract ``lcmt_vehicle_actuation`` (from an ``LcmSubscriberSystem``).
        state: input (7), the vehicle's state (its speed ``v`` sets the braking fade).
        actuation: output (2) ``[steer_rate rad/s, accel m/s^2]``: the newest accepted command
            while it is younger than ``timeout_s``; otherwise ``[0, -brake_decel_mps2]``: a car
            that loses its controller stops. A negative acceleration (braking) fades to 0 below
            ``BRAKE_BLEND_MPS`` (0.5 m/s) in both cases, as a car's brakes do: a braking command
            held at standstill (the station's fallback while its states arrive late) leaves the
            car standing instead of reversing it, which the vehicle models would otherwise do
            (their acceleration is signed) and the multi-body truth cannot integrate.
        status: output, abstract :class:`pcvfe_drake.hardware.watchdog.StreamStatus` named
            ``"actuation"``.

    Rate: a periodic unrestricted update every ``period_s`` checks a new message (non-finite
    commands and out-of-order ones are rejected; lateness is not checked here).
    """

    def __init__(self, *, period_s: float, timeout_s: float, brake_decel_mps2: float) -> None:
        super().__init__()
        require_positive("ActuationReceiver", period_s=period_s, brake_decel_mps2=brake_decel_mps2)
        self.limits = StreamLimits(timeout_s)
        self.brake_decel_mps2 = float(brake_decel_mps2)
        self._message_port = self.DeclareAbstractInputPort(
            "message", AbstractValue.Make(lcmt_vehicle_actuation())
        )
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._u_index = self.DeclareDiscreteState(NU)
        self._status_index = self.DeclareAbstractState(
            AbstractValue.Make(StreamStatus(name="actuation", last_seen_utime=0))
        )
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=period_s, offset_sec=0.0, update=self._check
        )
        self.DeclareVectorOutputPort("actuation", NU, self._calc_actuation)
        self.DeclareStateOutputPort("status", self._status_index)

    def _status(self, context: Context) -> StreamStatus:
        return context.get_abstract_state(self._status_index).get_value()

    def _check(self, context: Context, state: State) -> EventStatus:
        t = context.get_time()
        status = self._status(context)
        msg = self._message_port.Eval(context)
        if is_new(status, msg.utime):
            u = np.array([msg.steer_rate, msg.accel], dtype=float)
            problem = "" if np.all(np.isfinite(u)) else "non_finite"
            status, accepted = self.limits.check(status, t, msg.utime, problem)
            if accepted:
                state.get_mutable_discrete_state(self._u_index).set_value(u)
        status = self.limits.settle(status, t)
        state.get_mutable_abstract_state(self._status_index).set_value(status)
        return EventStatus.Succeeded()

    def _calc_actuation(self, context: Context, output: BasicVector) -> None:
        if self.limits.condition(self._status(context), context.get_time()) == "ok":
            steer_rate, accel = context.get_discrete_state(self._u_index).value()
        else:
            steer_rate, accel = 0.0, -self.brake_decel_mps2
        if accel < 0.0:
            v = float(self._state_port.Eval(context)[V])
            accel *= min(max(v / BRAKE_BLEND_MPS, 0.0), 1.0) if math.isfinite(v) else 1.0
        output.SetFromVector([steer_rate, accel])
