"""ActuationSender: the command and the state timestamp it follows, in one message."""

import numpy as np
import pytest

from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation
from pcvfe_drake.systems.actuation_sender import ActuationSender


def test_message_carries_command_time_and_state_utime():
    sender = ActuationSender()
    ctx = sender.CreateDefaultContext()
    ctx.SetTime(1.25)
    sender.GetInputPort("actuation").FixValue(ctx, [0.1, -2.0])
    sender.GetInputPort("state_utime").FixValue(ctx, [1_240_000.0])
    msg = sender.GetOutputPort("message").Eval(ctx)
    assert isinstance(msg, lcmt_vehicle_actuation)
    assert (msg.utime, msg.state_utime, msg.steer_rate, msg.accel) == (
        1_250_000,
        1_240_000,
        0.1,
        -2.0,
    )
    sender.GetInputPort("actuation").FixValue(ctx, [np.nan, 0.0])
    with pytest.raises(ValueError, match="'actuation'.*not finite"):
        sender.GetOutputPort("message").Eval(ctx)
