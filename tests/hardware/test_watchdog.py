"""The message watchdog's decisions (core, no pydrake)."""

import math

import pytest

from pcvfe_drake.hardware.watchdog import (
    StationStatus,
    StreamStatus,
    check_message,
    is_new,
    note_condition,
    stream_condition,
)


def feed(status, t_s, utime, problem=""):
    return check_message(status, t_s, utime, problem=problem, max_delay_s=0.05)


def test_in_order_messages_are_accepted_and_counted():
    s = StreamStatus(name="state")
    for k in range(5):
        s, ok = feed(s, 10.0 + 0.01 * k + 0.002, 1000 + 10_000 * k)
        assert ok
    assert s.accepted == 5 and s.rejected_count() == 0
    assert s.accepted_utime == 41_000
    # The clock offset (station 10 s ahead of the sender) is not a delay.
    assert s.min_delay_s == pytest.approx(10.0 + 0.002 - 0.001)
    assert stream_condition(s, 10.05, timeout_s=0.05) == "ok"


def test_out_of_order_repeated_late_and_bad_payloads_are_rejected_with_their_reason():
    s, _ = feed(StreamStatus(), 1.0, 1_000_000)
    s, ok = feed(s, 1.01, 990_000)
    assert not ok and s.last_rejection == "out_of_order"
    s, ok = feed(s, 1.02, 1_000_000)  # same timestamp again
    assert not ok and s.rejected_count("out_of_order") == 2
    # Sent at 1.01 s, arriving at 1.2 s: 0.19 s more delay than the best seen.
    s, ok = feed(s, 1.2, 1_010_000)
    assert not ok and s.last_rejection == "late"
    # 0.04 s extra delay is within max_delay_s.
    s, ok = feed(s, 1.06, 1_020_000)
    assert ok and s.last_delay_s == pytest.approx(0.04 - 0.05 * 0.06)  # drift allowance
    for reason in ("non_finite", "invalid", "malformed"):
        s, ok = feed(s, 1.07, 1_030_000, problem=reason)
        assert not ok and s.last_rejection == reason
    assert s.accepted == 2 and s.rejected_count() == 6
    with pytest.raises(ValueError, match="unknown rejection"):
        feed(s, 1.1, 2_000_000, problem="bogus")


def test_conditions_waiting_ok_timeout_and_counted_timeouts():
    s = StreamStatus(name="camera")
    assert stream_condition(s, 5.0, 0.3) == "waiting"
    s, _ = feed(s, 1.0, 1)
    s = note_condition(s, stream_condition(s, 1.0, 0.3))
    assert stream_condition(s, 1.29, 0.3) == "ok"
    assert stream_condition(s, 1.31, 0.3) == "timeout"
    s = note_condition(s, stream_condition(s, 1.31, 0.3))
    s = note_condition(s, stream_condition(s, 1.4, 0.3))
    assert s.timeouts == 1
    assert math.isinf(StreamStatus().age_s(3.0))


def test_is_new_tells_a_held_message_from_a_new_one():
    s = StreamStatus(last_seen_utime=0)
    assert not is_new(s, 0)
    s, _ = feed(s, 0.0, 5)
    assert not is_new(s, 5) and is_new(s, 6)


def test_station_status_reason_names_the_stream_and_the_last_rejection():
    state, _ = feed(StreamStatus(name="state"), 1.0, 10)
    state, _ = feed(state, 1.0, 20, problem="non_finite")
    status = StationStatus(state="timeout", camera="ok", streams=(state,), source="lcm")
    assert not status.ok
    assert status.reason() == "state timeout (last rejection: non_finite)"
    assert StationStatus().ok and StationStatus().reason() == "ok"
    assert status.to_dict()["streams"]["state"]["rejected"] == {"non_finite": 1}


def test_a_sender_clock_slightly_slower_than_the_station_is_not_late():
    # The sender's clock runs 2 % slow (a simulated car that cannot quite keep up): over 10 s
    # its messages fall 0.2 s behind, four times max_delay_s, yet none is late.
    s = StreamStatus()
    for k in range(1000):
        t = 0.01 * k
        s, ok = feed(s, t + 0.001, int(round(t * 0.98 * 1e6)))
        assert ok, (k, s.last_rejection)
    # A 60 ms hiccup still is late.
    s, ok = feed(s, 10.061 + 0.001, int(round(10.0 * 0.98 * 1e6)))
    assert not ok and s.last_rejection == "late"


def test_stream_limits_check_and_settle_and_name_bad_values():
    from pcvfe_drake.hardware.watchdog import StreamLimits, require_positive

    limits = StreamLimits(timeout_s=0.1, max_delay_s=0.05)
    s, ok = limits.check(StreamStatus(), 1.0, 1_000_000)
    assert ok and limits.condition(s, 1.05) == "ok"
    s = limits.settle(s, 1.0)
    assert limits.settle(s, 1.2).timeouts == 1
    assert StreamLimits(timeout_s=0.1).max_delay_s == math.inf
    with pytest.raises(ValueError, match="Rx: period_s must be a finite number > 0"):
        require_positive("Rx", period_s=0.0)
    with pytest.raises(ValueError, match="timeout_s"):
        StreamLimits(timeout_s=float("nan"))
