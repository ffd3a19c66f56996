"""Every message of a stream, each at its own time: the receivers' queue and play-out.

An ``LcmSubscriberSystem`` holds only the newest message. When the station's process does not
get a core for a while (a loaded machine), several state messages arrive between two checks of
its receiver and all but the newest are lost; the station then catches up on the lost wall time
by running its ticks back to back, sees no new message in them, and the state times out
although every message arrived. The hardware station's receivers avoid both:

- :class:`MessageQueue` keeps every message a ``DrakeLcm`` subscription delivers, with the
  wall-clock time it was handed over (bounded: the oldest is dropped beyond ``capacity``,
  counted);
- each check of the receiver drains the queue and decides on every message in arrival order
  (:func:`admit`: the watchdog's payload checks, then ``duplicate`` for a timestamp already
  accepted, ``out_of_order`` for an older one, ``late`` for one whose delay exceeds the smallest
  seen by more than ``max_delay_s``);
- an accepted message is *due* at the station time at which it would have arrived had the
  station kept pace with the wall clock and the network been as fast as it has ever been
  (``utime`` plus the reference delay, both on the station's clock). :func:`release` hands out,
  at each check, the newest message that is due, holding newer ones back at most
  ``max_hold_s`` (default 0: always the newest). With a hold, a station that runs behind real
  time and catches up sees each message at its own tick, as an on-time station would, instead
  of the newest one held over several ticks (the fitter, which samples the station's state at
  100 Hz, gets each sample at its time stamp), at the price of giving the controller states
  up to ``max_hold_s`` older while it lags;
- the timeout counts on the wall clock as the station maps it (``StreamStatus.age_s``): the late
  ticks of a stall run at one wall instant and do not age the data, so a station that catches
  up does not time out a stream whose messages all arrived.

Clocks. On the simulated clock (``wall_clock=False``, tests in one process) a message arrives
at the check that drains it. On the wall clock (hardware) the arrival is the wall time at which
the subscription handed it over, mapped to the station's clock through the pacing origin
``wall - t / rate``; the origin is the smallest such value seen (a paced simulator never runs
ahead of the wall clock, so the smallest is the on-time one; the station's lag behind real time
is the difference), allowed to rise 0.5 %/s (``ORIGIN_DRIFT``) and re-anchored when the lag
exceeds ``max_lag_s`` (a paused or re-paced simulator), so a wrong origin is soon forgotten.
Holding is bounded: the current message is never older than the newest accepted one by more than
``max_hold_s``; a station that stays further behind skips ahead to fresh states.

``late`` is judged at the check, on the station's clock: a message the station drains while it
catches up is not late for being drained late (it sat in the station's own socket), only one
that is older than the station's present by more than ``max_delay_s`` beyond the best delay.

Plain Python (no pydrake): the receiver LeafSystems keep a :class:`Playout` in abstract state.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, replace

from pcvfe_drake.hardware.watchdog import (
    REJECTIONS,
    StreamStatus,
    note_condition,
    reference_delay,
    require_positive,
    stream_condition,
    with_rejection,
)

ORIGIN_DRIFT = 0.005
"""How fast [s/s] the estimated pacing origin may rise (0.5 %/s): an origin that is too early
(a re-paced simulator) is forgotten, 50 ms in 10 s, while a lag of a stall is barely touched."""


@dataclass(frozen=True)
class Arrival:
    """One message as the subscription delivered it."""

    data: bytes
    wall_s: float
    """``time.monotonic()`` when the subscription handed it over [s]."""


class MessageQueue:
    """Every message of one LCM channel between two checks of its receiver (thread-safe).

    ``push`` is the subscription's handler (``lcm.Subscribe(channel, queue.push)``);
    ``drain`` takes everything received since the last drain, oldest first. Beyond
    ``capacity`` messages the oldest is dropped and counted in ``dropped``. The queue refers to
    nothing else (in particular not to the ``DrakeLcm``), so a subscription holding it makes no
    reference cycle through C++ that Python could not collect.
    """

    def __init__(self, capacity: int = 1000, clock=time.monotonic) -> None:
        if not (isinstance(capacity, int) and capacity > 0):
            raise ValueError(f"MessageQueue: capacity must be an int > 0, got {capacity!r}")
        self.capacity = capacity
        self._clock = clock
        self._items: deque[Arrival] = deque()
        self._lock = threading.Lock()
        self.received = 0
        self.dropped = 0

    def push(self, data: bytes, wall_s: float | None = None) -> None:
        arrival = Arrival(bytes(data), self._clock() if wall_s is None else float(wall_s))
        with self._lock:
            self._items.append(arrival)
            self.received += 1
            while len(self._items) > self.capacity:
                self._items.popleft()
                self.dropped += 1

    def drain(self) -> list[Arrival]:
        with self._lock:
            items = list(self._items)
            self._items.clear()
        return items

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)


@dataclass(frozen=True)
class Pending:
    """An accepted message waiting for its time."""

    utime: int
    due_s: float
    """Station time [s] from which it is the stream's current message."""
    payload: object
    arrival_s: float = math.nan
    """Station time [s] at which it arrived (its wall-clock arrival on the station's clock)."""


@dataclass(frozen=True)
class Playout:
    """A receiver's bookkeeping of one stream: the watchdog's :class:`StreamStatus` and the
    accepted messages not yet due, oldest first."""

    status: StreamStatus
    pending: tuple[Pending, ...] = ()


@dataclass(frozen=True)
class PlayoutLimits:
    """What a queue-draining receiver accepts and when it hands a message out.

    ``timeout_s``: no message handed out for this long -> condition ``timeout``;
    ``max_delay_s``: allowed delay above the best one (``late``); ``wall_clock``: delays on the
    wall clock (hardware) or on the station's time (tests in one process); ``rate``: the
    station's pace (simulated seconds per wall second); ``max_pending``: accepted messages
    kept waiting at most (beyond it the oldest are skipped, counted as ``superseded``);
    ``max_lag_s``: a lag behind real time beyond this re-anchors the pacing origin;
    ``max_hold_s``: the current message is never older than the newest accepted one by more
    than this (0: always the newest; the hardware station uses ``hardware.playout_hold_s``).
    """

    timeout_s: float
    max_delay_s: float = math.inf
    wall_clock: bool = False
    rate: float = 1.0
    max_pending: int = 200
    max_lag_s: float = 2.0
    max_hold_s: float = 0.0

    def __post_init__(self) -> None:
        require_positive(
            "PlayoutLimits", timeout_s=self.timeout_s, rate=self.rate, max_lag_s=self.max_lag_s
        )
        if not (math.isfinite(self.max_hold_s) and self.max_hold_s >= 0):
            raise ValueError(f"PlayoutLimits: max_hold_s must be >= 0, got {self.max_hold_s!r}")
        if not self.max_delay_s > 0:
            raise ValueError(f"PlayoutLimits: max_delay_s must be > 0, got {self.max_delay_s!r}")

    def condition(self, status: StreamStatus, t_s: float) -> str:
        return stream_condition(status, t_s, self.timeout_s)


def station_clock(
    status: StreamStatus, t_s: float, wall_s: float | None, limits: PlayoutLimits
) -> StreamStatus:
    """``status`` with the pacing origin and the lag behind real time updated at a check at
    station time ``t_s`` and wall time ``wall_s`` (None: the simulated clock, no lag)."""
    if wall_s is None:
        return status
    here = wall_s - t_s / limits.rate
    # The smallest origin seen, allowed to rise like the reference delay: an origin taken from
    # a check before the pacing started (or before a re-pacing) is forgotten within seconds.
    allowed = status.clock_origin_s
    if math.isfinite(allowed):
        allowed += ORIGIN_DRIFT * max(0.0, wall_s - status.clock_origin_wall_s)
    origin = min(allowed, here)
    lag = (wall_s - origin) * limits.rate - t_s
    if lag > limits.max_lag_s:
        origin, lag = here, 0.0
        status = replace(status, clock_resets=status.clock_resets + 1)
    return replace(
        status,
        clock_origin_s=origin,
        clock_origin_wall_s=wall_s,
        lag_s=lag,
        max_lag_s=max(status.max_lag_s, lag),
        lag_sum_s=status.lag_sum_s + lag,
    )


def arrival_position(status: StreamStatus, t_s: float, wall_s: float | None, rate: float) -> float:
    """Station time [s] at which a message handed over at ``wall_s`` arrived (the check's time
    ``t_s`` on the simulated clock)."""
    if wall_s is None or not math.isfinite(status.clock_origin_s):
        return t_s
    return (wall_s - status.clock_origin_s) * rate


def admit(
    playout: Playout,
    t_s: float,
    utime: int,
    *,
    position_s: float,
    payload: object,
    problem: str,
    limits: PlayoutLimits,
) -> Playout:
    """Decide on one drained message (timestamp ``utime`` [us], arrived at station time
    ``position_s``) at a check at station time ``t_s``; an accepted one joins the pending
    messages with its due time."""
    status = playout.status
    utime = int(utime)
    status = replace(status, last_seen_utime=utime)
    if problem:
        if problem not in REJECTIONS:
            raise ValueError(f"unknown rejection reason {problem!r} (known: {REJECTIONS})")
        return replace(playout, status=with_rejection(status, problem, t_s))
    newest = status.admitted_utime
    if newest is not None and utime == newest:
        return replace(playout, status=with_rejection(status, "duplicate", t_s))
    if newest is not None and utime < newest:
        return replace(playout, status=with_rejection(status, "out_of_order", t_s))
    sent = utime * 1e-6
    delay = position_s - sent
    reference = reference_delay(status, position_s)
    if math.isfinite(reference) and t_s - sent - reference > limits.max_delay_s:
        return replace(playout, status=with_rejection(status, "late", t_s))
    reference = min(reference, delay)
    status = replace(
        status,
        admitted_utime=utime,
        min_delay_s=reference,
        min_delay_t_s=position_s,
        last_delay_s=delay - reference,
        accepted=status.accepted + 1,
    )
    pending = (*playout.pending, Pending(utime, sent + reference, payload, position_s))
    skipped = max(0, len(pending) - limits.max_pending)
    if skipped:
        pending = pending[skipped:]
        status = replace(status, superseded=status.superseded + skipped)
    return Playout(status, pending)


def release(playout: Playout, t_s: float, limits: PlayoutLimits) -> tuple[Playout, Pending | None]:
    """The newest pending message due at station time ``t_s`` (or within ``max_hold_s`` of
    the newest accepted one; None: none), the due ones before it counted as ``superseded``;
    the check counted, and a fresh one when a message is handed out; the transition to
    ``timeout`` counted."""
    pending = playout.pending
    # Due now, or so far behind the newest accepted message that holding it would make the
    # stream's current message older than max_hold_s.
    until = t_s
    if pending:
        until = max(t_s, pending[-1].due_s - limits.max_hold_s)
    n_due = 0
    while n_due < len(pending) and pending[n_due].due_s <= until + 1e-9:
        n_due += 1
    status = replace(playout.status, checks=playout.status.checks + 1)
    out = None
    if n_due:
        out = pending[n_due - 1]
        status = replace(
            status,
            accepted_utime=out.utime,
            accepted_t_s=t_s,
            accepted_lag_s=status.lag_s,
            released=status.released + 1,
            superseded=status.superseded + n_due - 1,
            hold_sum_s=status.hold_sum_s + max(0.0, out.arrival_s - t_s),
        )
    status = note_condition(status, limits.condition(status, t_s))
    return Playout(status, pending[n_due:]), out


def check_queue(
    playout: Playout,
    t_s: float,
    wall_s: float | None,
    arrivals: list[tuple[int, float, object, str]],
    limits: PlayoutLimits,
) -> tuple[Playout, Pending | None]:
    """One check of a receiver: the clock, every drained message ``(utime, wall_s, payload,
    problem)`` in arrival order, then the release. ``wall_s`` None: the simulated clock."""
    status = station_clock(playout.status, t_s, wall_s, limits)
    playout = replace(playout, status=status)
    for utime, arrived_wall_s, payload, problem in arrivals:
        position = arrival_position(
            playout.status, t_s, arrived_wall_s if wall_s is not None else None, limits.rate
        )
        playout = admit(
            playout,
            t_s,
            utime,
            position_s=position,
            payload=payload,
            problem=problem,
            limits=limits,
        )
    return release(playout, t_s, limits)


def drain_and_check(
    queue: MessageQueue,
    decode,
    playout: Playout,
    t_s: float,
    wall_s: float | None,
    limits: PlayoutLimits,
) -> tuple[Playout, Pending | None]:
    """A receiver's whole check: every message waiting in ``queue``, decoded by ``decode(data)
    -> (utime, payload, problem)``, through :func:`check_queue`."""
    arrivals = []
    for item in queue.drain():
        utime, payload, problem = decode(item.data)
        arrivals.append((utime, item.wall_s, payload, problem))
    return check_queue(playout, t_s, wall_s, arrivals, limits)
