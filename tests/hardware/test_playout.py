"""The receivers' queue and play-out (core, no pydrake)."""

import math

import pytest

from pcvfe_drake.hardware.playout import (
    MessageQueue,
    Playout,
    PlayoutLimits,
    check_queue,
    station_clock,
)
from pcvfe_drake.hardware.watchdog import StreamStatus


def test_the_queue_keeps_every_message_in_order_up_to_its_capacity():
    queue = MessageQueue(capacity=3, clock=lambda: 5.0)
    for k in range(5):
        queue.push(b"%d" % k)
    assert len(queue) == 3 and queue.dropped == 2 and queue.received == 5
    items = queue.drain()
    assert [i.data for i in items] == [b"2", b"3", b"4"] and items[0].wall_s == 5.0
    assert queue.drain() == []
    with pytest.raises(ValueError, match="capacity"):
        MessageQueue(capacity=0)


def test_on_the_simulated_clock_a_burst_is_handed_out_newest_first_and_counted():
    limits = PlayoutLimits(timeout_s=0.05, max_delay_s=0.05)
    p = Playout(StreamStatus(name="state"))
    burst = [(k * 10_000, math.nan, k, "") for k in range(4)]
    p, out = check_queue(p, 0.04, None, burst, limits)
    assert out.payload == 3 and p.status.superseded == 3 and p.pending == ()
    p, out = check_queue(p, 0.05, None, [(30_000, math.nan, 9, "")], limits)
    assert out is None and p.status.last_rejection == "duplicate"
    assert p.status.checks == 2 and p.status.released == 1


def test_a_lagging_station_keeps_messages_until_their_tick_and_a_long_lag_reanchors():
    limits = PlayoutLimits(
        timeout_s=0.05, max_delay_s=0.05, wall_clock=True, max_lag_s=0.5, max_hold_s=0.1
    )
    p = Playout(StreamStatus())
    p, _ = check_queue(p, 0.0, 10.0, [], limits)  # on time: origin 10 s
    # Messages of 0..40 ms, 1 ms on the wire, drained at 60 ms wall by the check of 10 ms.
    arrivals = [(k * 10_000, 10.0 + k * 0.01 + 0.001, k, "") for k in range(5)]
    p, out = check_queue(p, 0.01, 10.06, arrivals, limits)
    assert p.status.lag_s == pytest.approx(0.05 - 0.005 * 0.06)  # the origin may rise 0.5 %/s
    outs = [out.payload]
    for k in range(2, 6):  # the late ticks, back to back at one wall instant
        p, out = check_queue(p, k * 0.01, 10.06, [], limits)
        outs.append(out.payload if out else None)
    # One message per tick, in order, none skipped: each at (about) its own tick.
    assert outs[-1] == 4 and outs == list(range(outs[0], 5)) + [None] * (outs[0])
    assert p.status.superseded == outs[0] and p.status.rejected_count() == 0
    # A paused simulator (2 s behind): the origin is re-anchored, nothing waits for 2 s.
    s = station_clock(p.status, 0.05, 12.1, limits)
    assert s.clock_resets == 1 and s.lag_s == 0.0 and s.clock_origin_s == pytest.approx(12.05)


def test_holding_is_bounded_a_station_far_behind_skips_ahead():
    limits = PlayoutLimits(timeout_s=0.05, wall_clock=True, max_hold_s=0.03)
    p, _ = check_queue(Playout(StreamStatus()), 0.0, 10.0, [], limits)
    arrivals = [(k * 10_000, 10.0 + k * 0.01 + 0.001, k, "") for k in range(20)]
    p, out = check_queue(p, 0.01, 10.2, arrivals, limits)  # 190 ms behind
    newest_due = p.pending[-1].due_s if p.pending else None
    assert out.payload >= 19 - 3 and p.pending and newest_due - out.due_s <= 0.03 + 1e-9


def test_pending_messages_are_bounded():
    limits = PlayoutLimits(timeout_s=0.05, wall_clock=True, max_pending=2, max_hold_s=1.0)
    p, _ = check_queue(Playout(StreamStatus()), 0.0, 10.0, [], limits)
    arrivals = [(k * 10_000, 10.0 + k * 0.01, k, "") for k in range(5)]
    p, out = check_queue(p, 0.0, 10.04, arrivals, limits)
    # Only the two newest stay; the first released was the oldest still kept.
    assert p.status.superseded == 3 and out is None and [q.payload for q in p.pending] == [3, 4]


def test_holding_zero_hands_out_the_newest():
    limits = PlayoutLimits(timeout_s=0.05, wall_clock=True)  # max_hold_s = 0
    p, _ = check_queue(Playout(StreamStatus()), 0.0, 10.0, [], limits)
    arrivals = [(k * 10_000, 10.0 + k * 0.01 + 0.001, k, "") for k in range(5)]
    p, out = check_queue(p, 0.01, 10.06, arrivals, limits)
    assert out.payload == 4 and p.pending == () and p.status.superseded == 4
    with pytest.raises(ValueError, match="max_hold_s"):
        PlayoutLimits(timeout_s=0.05, max_hold_s=-1.0)
