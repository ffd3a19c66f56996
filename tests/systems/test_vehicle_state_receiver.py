"""VehicleStateReceiver: every queued state message is checked, faults give NaN or a held state
and a reason, and a station that catches up on a stall sees each message at its own tick."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from pcvfe_drake.hardware.playout import MessageQueue
from pcvfe_drake.lcmtypes import lcmt_vehicle_state
from pcvfe_drake.systems.vehicle_state_receiver import VehicleStateReceiver

X = np.array([1.0, 2.0, 0.01, 3.0, 0.5, 0.1, 0.02])


def message(utime, x=X, valid=True):
    msg = lcmt_vehicle_state()
    msg.utime, msg.state, msg.valid = int(utime), [float(v) for v in x], valid
    return msg


class Rig:
    def __init__(self, **kwargs):
        self.queue = MessageQueue()
        options = dict(period_s=0.005, timeout_s=0.05, max_delay_s=0.03) | kwargs
        self.rx = VehicleStateReceiver(queue=self.queue, **options)
        self.sim = Simulator(self.rx)
        self.ctx = self.sim.get_mutable_context()
        self.sim.Initialize()

    def send(self, msg, until, wall_s=None, raw=False):
        self.queue.push(msg if raw else msg.encode(), wall_s)
        self.sim.AdvanceTo(until)

    def state(self):
        return self.rx.GetOutputPort("state").Eval(self.ctx)

    def utime(self):
        return self.rx.GetOutputPort("state_utime").Eval(self.ctx)[0]

    def status(self):
        return self.rx.GetOutputPort("status").Eval(self.ctx)


def test_waits_for_the_first_message_then_passes_the_state_and_its_utime():
    rig = Rig()
    rig.sim.AdvanceTo(0.02)
    assert np.all(np.isnan(rig.state())) and rig.utime() == -1
    assert rig.status().accepted == 0
    rig.send(message(20_000), 0.03)
    np.testing.assert_array_equal(rig.state(), X)
    assert rig.utime() == 20_000
    assert rig.status().accepted == 1 and rig.status().released == 1


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
    # Checks run every 5 ms; a message queued at time T is checked at the next multiple of 5 ms.
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
    rig.send(message(10_000, X * 4), 0.041)
    assert rig.status().last_rejection == "duplicate"
    # Newer, checked at 45 ms: delay 33 ms, 43 ms above the best: more than max_delay_s 30 ms.
    rig.send(message(12_000, X * 5), 0.046)
    assert rig.status().last_rejection == "late"
    np.testing.assert_array_equal(rig.state(), X)  # the last good state, held
    rig.send(message(0)._get_packed_fingerprint() + b"cut short", 0.051, raw=True)
    assert rig.status().last_rejection == "malformed"
    s = rig.status()
    assert s.accepted == 1
    assert dict(s.rejected) == {
        "duplicate": 1,
        "invalid": 1,
        "late": 1,
        "malformed": 1,
        "non_finite": 1,
        "out_of_order": 1,
    }
    # Checked at 55 ms with delay 15 ms: 22 ms above the best (which may rise 5 %/s), accepted.
    rig.send(message(40_000, X * 6), 0.056)
    np.testing.assert_array_equal(rig.state(), X * 6)
    assert rig.status().accepted == 2


def test_every_message_of_a_burst_is_checked_and_the_newest_due_one_handed_out():
    rig = Rig()
    rig.send(message(0), 0.001)
    # Three messages arrive between two checks (simulated clock: they arrive at the check):
    # each is checked, the newest is current, the two before it are superseded.
    for k in (1, 2, 3):
        rig.queue.push(message(k * 1000, X * k).encode())
    rig.sim.AdvanceTo(0.006)
    np.testing.assert_array_equal(rig.state(), X * 3)
    s = rig.status()
    assert s.accepted == 4 and s.released == 2 and s.superseded == 2 and s.rejected_count() == 0


class FakeWall:
    """A wall clock the test sets (the receiver reads it at each check)."""

    def __init__(self, t):
        self.t = t

    def __call__(self):
        return self.t


def test_a_station_catching_up_after_a_stall_gets_each_state_at_its_own_tick():
    wall = FakeWall(100.0)
    # Messages may be held 100 ms for their ticks (hardware.playout_hold_s): above the stall.
    rig = Rig(period_s=0.01, max_delay_s=0.1, max_hold_s=0.1, wall_clock=True, clock=wall)
    sent = []

    def car_sends_until(t_car):  # the car's 100 Hz messages, each 2 ms on the wire
        k = len(sent)
        while k * 0.01 <= t_car + 1e-9:
            rig.queue.push(message(k * 10_000, X + k).encode(), 100.0 + k * 0.01 + 0.002)
            sent.append(k)
            k += 1

    seen = {}
    for k in range(6):  # on time: the check at t sees the car's message of t - 10 ms
        car_sends_until(k * 0.01 - 0.01)
        wall.t = 100.0 + k * 0.01 + 0.0005
        rig.sim.AdvanceTo(k * 0.01 + 0.001)
        seen[k] = rig.utime()
    # The station's process stalls for 60 ms while the car keeps sending; then the simulator
    # runs its late ticks back to back at one wall instant. Each tick takes its own message.
    car_sends_until(0.11)
    wall.t = 100.115
    for k in range(6, 12):
        rig.sim.AdvanceTo(k * 0.01 + 0.001)
        seen[k] = rig.utime()
        np.testing.assert_array_equal(rig.state(), X + seen[k] / 10_000)
    assert [seen[k] for k in range(1, 12)] == [(k - 1) * 10_000 for k in range(1, 12)]
    s = rig.status()
    assert s.timeouts == 0 and s.rejected_count() == 0 and s.superseded == 0
    # At the tick of 60 ms (the origin may rise 0.5 %/s: 0.6 ms over the 115 ms).
    assert s.max_lag_s == pytest.approx(0.115 - 0.0005 - 0.06, abs=1e-3)
    # The newest messages (sent at 100.10 and 100.11 s) wait for their ticks.
    assert s.accepted == 12 and s.released == 11


def test_without_holding_a_stall_gives_the_newest_state_and_no_false_timeout():
    # playout_hold_s = 0 (the default): the newest message at every check. The late ticks of a
    # 60 ms stall see no new message, but they run at one wall instant: the data do not age
    # in them (the lag shrinks as the station's time advances), so no timeout.
    wall = FakeWall(100.0)
    rig = Rig(period_s=0.01, max_delay_s=0.1, wall_clock=True, clock=wall)
    for k in range(6):
        rig.queue.push(message(k * 10_000, X + k).encode(), 100.0 + k * 0.01 + 0.002)
        wall.t = 100.0 + k * 0.01 + 0.005
        rig.sim.AdvanceTo(k * 0.01 + 0.006)
    for k in range(6, 12):
        rig.queue.push(message(k * 10_000, X + k).encode(), 100.0 + k * 0.01 + 0.002)
    wall.t = 100.125
    seen = []
    for k in range(6, 13):
        rig.sim.AdvanceTo(k * 0.01 + 0.001)
        seen.append(rig.utime())
        assert np.all(np.isfinite(rig.state()))
    assert seen[0] == 110_000 and set(seen) == {110_000}
    s = rig.status()
    assert s.timeouts == 0 and s.superseded == 5 and s.rejected_count() == 0


def test_the_first_message_waited_for_is_handed_out_at_initialization():
    """The controller's first update runs at t = 0 beside the receiver's first check and sees
    the state from before it: the initialization that waited for the message hands it out."""
    queue = MessageQueue()
    rx = VehicleStateReceiver(
        queue=queue, period_s=0.01, timeout_s=0.05, max_delay_s=0.03, first_message_timeout_s=1.0
    )
    queue.push(message(0).encode())
    sim = Simulator(rx)
    sim.Initialize()
    ctx = sim.get_context()
    np.testing.assert_array_equal(rx.GetOutputPort("state").Eval(ctx), X)
    assert rx.GetOutputPort("status").Eval(ctx).accepted == 1
    empty = VehicleStateReceiver(
        queue=MessageQueue(), period_s=0.01, timeout_s=0.05, max_delay_s=0.03,
        first_message_timeout_s=0.05, source="PCVFE_STATE at memq://",
    )  # fmt: skip
    with pytest.raises(RuntimeError, match="no state message on PCVFE_STATE at memq://"):
        Simulator(empty).Initialize()
