"""VehicleStateSender: a state vector as the vehicle's LCM state message (the vehicle side)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem

from pcvfe_drake.lcmtypes import lcmt_vehicle_state
from pcvfe_drake.vehicle.single_track import NX


class VehicleStateSender(LeafSystem):
    """Packs the ST state into ``lcmt_vehicle_state`` for an ``LcmPublisherSystem``.

    .. pydrake_system::

        name: VehicleStateSender
        input_ports:
        - state
        output_ports:
        - message

    Ports:
        state: input (7) ``[sx m, sy m, delta rad, v m/s, psi rad, psi_dot rad/s, beta rad]``.
        message: output, abstract ``lcmt_vehicle_state`` stamped with the context time [us];
            ``valid`` is False when a component is not finite.

    A pure output calc; the publisher's period (the scenario's ``hardware.state_period_s``)
    sets the rate.
    """

    def __init__(self) -> None:
        super().__init__()
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self.DeclareAbstractOutputPort(
            "message", lambda: AbstractValue.Make(lcmt_vehicle_state()), self._calc
        )

    def _calc(self, context: Context, output: AbstractValue) -> None:
        x = np.asarray(self._state_port.Eval(context), dtype=float)
        msg = lcmt_vehicle_state()
        msg.utime = int(round(context.get_time() * 1e6))
        msg.state = [float(v) for v in x]
        msg.valid = bool(np.all(np.isfinite(x)))
        output.set_value(msg)
