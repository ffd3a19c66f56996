"""VehicleStateReceiver: accepted states pass, every fault gives NaN or a held state and a
reason."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from pcvfe_drake.lcmtypes import lcmt_vehicle_state
from pcvfe_drake.systems.vehicle_state_receiver import VehicleStateReceiver

X = np.array([1.0, 2.0, 0.01, 3.0, 0.5, 0.1, 0.02])


def message(utime, x=X, valid=True):
    msg = lcmt_vehicle_state()
    msg.utime, msg.state, msg.valid = int(utime), [float(v) for v in x], valid
    return msg


class Rig:
    def __init__(self):
        self.rx = VehicleStateReceiver(period_s=0.005, timeout_s=0.05, max_delay_s=0.03)
        self.sim = Simulator(self.rx)
        self.ctx = self.sim.get_mutable_context()
        self.port = self.rx.GetInputPort("message")
        self.port.FixValue(self.ctx, AbstractValue.Make(lcmt_vehicle_state()))
        self.sim.Initialize()

    def send(self, msg, until):
        self.port.FixValue(self.ctx, AbstractValue.Make(msg))
        self.sim.AdvanceTo(until)

    def state(self):
        return self.rx.GetOutputPort("state").Eval(self.ctx)

    def status(self):
        return self.rx.GetOutputPort("status").Eval(self.ctx)


def test_waits_for_the_first_message_then_passes_the_state_and_its_utime():
    rig = Rig()
    rig.sim.AdvanceTo(0.02)
    assert np.all(np.isnan(rig.state()))  # the subscriber's default message is not taken
    rig.send(message(20_000), 0.03)
    np.testing.assert_array_equal(rig.state(), X)
    assert rig.rx.GetOutputPort("state_utime").Eval(rig.ctx)[0] == 20_000
    assert rig.status().accepted == 1


def test_a_stream_that_stops_becomes_nan_after_the_timeout():
    rig = Rig()
    rig.send(message(10_000), 0.012)  # checked (accepted) at t = 0
    rig.sim.AdvanceTo(0.045)
    np.testing.assert_array_equal(rig.state(), X)  # held within the timeout
    rig.sim.AdvanceTo(0.07)
    assert np.all(np.isnan(rig.state()))
    assert rig.status().timeouts == 1
    rig.send(message(70_000), 0.08)  # recovers with the next good message
    np.testing.assert_array_equal(rig.state(), X)


def test_faulty_messages_are_rejected_and_the_last_good_state_is_held():
    # Checks run every 5 ms; a message fixed at time T is checked at the next multiple of 5 ms.
    rig = Rig()
    rig.send(message(10_000), 0.011)  # checked at t = 0: delay -10 ms (the best so far)
    bad_x = X.copy()
    bad_x[3] = np.nan
    rig.send(message(20_000, bad_x), 0.021)
    assert rig.status().last_rejection == "non_finite"
    rig.send(message(30_000, X * 2, valid=False), 0.031)
    assert rig.status().last_rejection == "invalid"
    rig.send(message(5_000, X * 3), 0.036)
    assert rig.status().last_rejection == "out_of_order"
    rig.send(message(500, X * 4), 0.041)
    # Newer, checked at 45 ms: delay 33 ms, 43 ms above the best: more than max_delay_s 30 ms.
    rig.send(message(12_000, X * 5), 0.046)
    assert rig.status().last_rejection == "late"
    np.testing.assert_array_equal(rig.state(), X)
    s = rig.status()
    assert s.accepted == 1
    assert dict(s.rejected) == {"invalid": 1, "late": 1, "non_finite": 1, "out_of_order": 2}
    # Checked at 50 ms with delay 10 ms: 20 ms above the best, accepted.
    rig.send(message(40_000, X * 6), 0.051)
    np.testing.assert_array_equal(rig.state(), X * 6)
    assert rig.status().accepted == 2
