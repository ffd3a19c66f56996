"""ActuationSender: the controller's actuation as an LCM message for the vehicle."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem

from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation
from pcvfe_drake.vehicle.single_track import NU


class ActuationSender(LeafSystem):
    """Packs ``[steer_rate, accel]`` into ``lcmt_vehicle_actuation`` for an
    ``LcmPublisherSystem``.

    .. pydrake_system::

        name: ActuationSender
        input_ports:
        - actuation
        - state_utime
        output_ports:
        - message

    Ports:
        actuation: input (2) ``[steer_rate rad/s, accel m/s^2]``.
        state_utime: input (1), ``utime`` [us] of the newest state the station accepted (-1:
            none), copied into the message so the vehicle side can measure the latency from a
            state to the command computed after it.
        message: output, abstract ``lcmt_vehicle_actuation`` stamped with the context time
            [us]. The NMPC's output is always finite; a non-finite input raises ``ValueError``
            naming it rather than sending it to a car.

    A pure output calc (no state, no events); the publisher's period sets the rate.
    """

    def __init__(self) -> None:
        super().__init__()
        self._actuation_port = self.DeclareVectorInputPort("actuation", NU)
        self._utime_port = self.DeclareVectorInputPort("state_utime", 1)
        self.DeclareAbstractOutputPort(
            "message", lambda: AbstractValue.Make(lcmt_vehicle_actuation()), self._calc
        )

    def _calc(self, context: Context, output: AbstractValue) -> None:
        u = np.asarray(self._actuation_port.Eval(context), dtype=float)
        if not np.all(np.isfinite(u)):
            raise ValueError(
                f"ActuationSender: input 'actuation' = {u.tolist()} is not finite at "
                f"t = {context.get_time():.3f} s"
            )
        msg = lcmt_vehicle_actuation()
        msg.utime = int(round(context.get_time() * 1e6))
        msg.state_utime = int(self._utime_port.Eval(context)[0])
        msg.steer_rate, msg.accel = float(u[0]), float(u[1])
        output.set_value(msg)
