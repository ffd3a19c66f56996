"""VehicleStateSender: the state, its time, and validity."""

import numpy as np

from pcvfe_drake.systems.vehicle_state_sender import VehicleStateSender


def test_message_holds_state_time_and_validity():
    sender = VehicleStateSender()
    ctx = sender.CreateDefaultContext()
    ctx.SetTime(0.37)
    x = np.arange(7, dtype=float)
    sender.GetInputPort("state").FixValue(ctx, x)
    msg = sender.GetOutputPort("message").Eval(ctx)
    assert msg.utime == 370_000 and msg.valid
    np.testing.assert_array_equal(msg.state, x)
    x[2] = np.inf
    sender.GetInputPort("state").FixValue(ctx, x)
    assert not sender.GetOutputPort("message").Eval(ctx).valid
