"""Message watchdog: what a station accepts from a stream of timestamped messages, and why not.

A car's sensor streams fail in a few ways; :func:`check_message` turns each into a decision and
:func:`stream_condition` into what the station outputs:

==================  =====================================================================
rejection           when
==================  =====================================================================
``non_finite``      a state with a NaN or infinite component
``invalid``         the sender marked the message invalid (no fix, ...)
``malformed``       the payload cannot be decoded (wrong size, unknown pixel format, ...)
``duplicate``       its timestamp is that of the newest accepted one (a repeat; the
                    queue-draining receivers of the LCM station, ``playout.py``)
``out_of_order``    its timestamp is older than the newest accepted one (the receivers that
                    look at a held message count repeats here too)
``late``            its transport delay exceeds the smallest delay seen so far by more than
                    ``max_delay_s`` (the sender's clock need not agree with the station's:
                    only differences of delay count; the smallest delay may rise by
                    ``DRIFT_ALLOWANCE`` per second, so two clocks whose rates differ by less
                    than that, a simulated vehicle that runs slightly slower than real time,
                    never make every message late)
==================  =====================================================================

A rejected message never reaches the station's outputs; the output holds the last accepted one
until ``timeout_s`` has passed without a new acceptance, then the stream's condition is
``timeout`` (``waiting`` before the first acceptance) and the station outputs its safe value
(NaN state, blank image). Every decision is counted in :class:`StreamStatus`.

Plain Python (no pydrake): the receiver LeafSystems keep a :class:`StreamStatus` in abstract state.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

CONDITIONS = ("ok", "waiting", "timeout")
"""What a stream's output is now: fresh data, nothing accepted yet, or no acceptance for longer
than the timeout. The numeric code of a condition is its index."""

REJECTIONS = ("non_finite", "invalid", "malformed", "duplicate", "out_of_order", "late")
"""Reasons a message is rejected."""

DRIFT_ALLOWANCE = 0.05
"""How fast [s/s] the reference (smallest) delay may rise: rate differences between the
sender's and the station's clocks up to 5 %."""


@dataclass(frozen=True)
class StreamStatus:
    """Bookkeeping of one message stream (immutable: every update returns a new one).

    Times: ``*_t_s`` on the station's clock [s]; ``*_utime`` the sender's timestamps [us].
    """

    name: str = ""
    last_seen_utime: int | None = None
    """Timestamp of the newest message looked at (to tell a new message from a held one)."""
    accepted_utime: int | None = None
    """Timestamp of the newest accepted message."""
    accepted_t_s: float = math.nan
    """Station time at which the newest accepted message was taken."""
    min_delay_s: float = math.inf
    """Reference delay: the smallest (station time - sender time) of the accepted messages,
    allowed to rise by ``DRIFT_ALLOWANCE`` per second since ``min_delay_t_s`` [s]."""
    min_delay_t_s: float = math.nan
    """Arrival time (the delay's clock) at which ``min_delay_s`` was set [s]."""
    last_delay_s: float = math.nan
    """Delay of the newest accepted message above ``min_delay_s`` [s]."""
    accepted: int = 0
    rejected: tuple[tuple[str, int], ...] = field(default_factory=tuple)
    """Rejection counts by reason, as ``((reason, count), ...)``."""
    last_rejection: str = ""
    last_rejection_t_s: float = math.nan
    timeouts: int = 0
    """How many times the stream went from ``ok`` to ``timeout``."""
    was_ok: bool = False
    admitted_utime: int | None = None
    """Timestamp of the newest accepted message, handed out or still pending (queue-draining
    receivers, ``pcvfe_drake.hardware.playout``; ``accepted_utime`` is the one handed out)."""
    released: int = 0
    """Accepted messages handed out (one per check at most)."""
    superseded: int = 0
    """Accepted messages never handed out: a newer one was due at the same check."""
    checks: int = 0
    """Checks of the receiver (``released / checks``: the share with a fresh message)."""
    clock_origin_s: float = math.inf
    """Wall time [s] of station time 0 on the pacing (the smallest ``wall - t / rate``)."""
    clock_origin_wall_s: float = math.nan
    """Wall time [s] of the check that last set ``clock_origin_s``."""
    lag_s: float = 0.0
    """How far the station's time was behind the wall clock at the last check [s]."""
    accepted_lag_s: float = 0.0
    """``lag_s`` at the check that handed out the newest accepted message [s]."""
    max_lag_s: float = 0.0
    lag_sum_s: float = 0.0
    """Sum of the lag over the checks [s] (``/ checks``: the mean lag)."""
    hold_sum_s: float = 0.0
    """Sum over the messages handed out of how long after their arrival (on the station's
    clock) the station's clock reached them [s]: the time a lagging station held them back."""
    clock_resets: int = 0
    """Times the pacing origin was re-anchored (a lag beyond the limit)."""

    def rejected_count(self, reason: str | None = None) -> int:
        """Rejections for ``reason`` (None: all)."""
        return sum(n for r, n in self.rejected if reason is None or r == reason)

    def age_s(self, t_s: float) -> float:
        """Seconds since the newest acceptance (inf before the first), on the wall clock as the
        station's clock maps it: a station catching up on a stall runs its late ticks at one
        wall instant, and its lag behind real time (``lag_s``, from the queue-draining
        receivers; 0 elsewhere) shrinks as fast as its time advances, so its data do not age
        in those ticks."""
        if not math.isfinite(self.accepted_t_s):
            return math.inf
        return t_s - self.accepted_t_s + (self.lag_s - self.accepted_lag_s)

    def to_dict(self) -> dict:
        out = {
            "accepted": self.accepted,
            "rejected": dict(self.rejected),
            "last_rejection": self.last_rejection,
            "timeouts": self.timeouts,
        }
        if self.checks:
            out.update(
                released=self.released,
                superseded=self.superseded,
                checks=self.checks,
                max_lag_s=self.max_lag_s,
                mean_lag_s=self.lag_sum_s / self.checks,
                mean_hold_s=self.hold_sum_s / max(self.released, 1),
                clock_resets=self.clock_resets,
            )
        return out


def with_rejection(status: StreamStatus, reason: str, t_s: float) -> StreamStatus:
    counts = dict(status.rejected)
    counts[reason] = counts.get(reason, 0) + 1
    return replace(
        status,
        rejected=tuple(sorted(counts.items())),
        last_rejection=reason,
        last_rejection_t_s=t_s,
    )


def is_new(status: StreamStatus, utime: int) -> bool:
    """True when a message with timestamp ``utime`` has not been looked at yet (a subscriber
    holds its latest message, so the same one is seen on every check until another arrives)."""
    return status.last_seen_utime is None or int(utime) != status.last_seen_utime


def check_message(
    status: StreamStatus,
    t_s: float,
    utime: int,
    *,
    problem: str = "",
    max_delay_s: float,
    arrival_s: float | None = None,
) -> tuple[StreamStatus, bool]:
    """Decide on a new message with timestamp ``utime`` [us] taken at station time ``t_s``.

    ``problem`` is a rejection reason the caller found in the payload (``"non_finite"``,
    ``"invalid"``, ``"malformed"``; empty: none). ``arrival_s`` is the clock the delay is
    measured on (default ``t_s``; the LCM station uses the wall clock, so a station that fell
    behind real time and catches up does not mistake fresh messages for late ones). Returns the
    new status and whether the message is accepted.
    """
    utime = int(utime)
    status = replace(status, last_seen_utime=utime)
    if problem:
        if problem not in REJECTIONS:
            raise ValueError(f"unknown rejection reason {problem!r} (known: {REJECTIONS})")
        return with_rejection(status, problem, t_s), False
    if status.accepted_utime is not None and utime <= status.accepted_utime:
        return with_rejection(status, "out_of_order", t_s), False
    arrival = t_s if arrival_s is None else float(arrival_s)
    delay = arrival - utime * 1e-6
    reference = reference_delay(status, arrival)
    if math.isfinite(reference) and delay - reference > max_delay_s:
        return with_rejection(status, "late", t_s), False
    reference = min(reference, delay)
    return (
        replace(
            status,
            accepted_utime=utime,
            accepted_t_s=t_s,
            min_delay_s=reference,
            min_delay_t_s=arrival,
            last_delay_s=delay - reference,
            accepted=status.accepted + 1,
        ),
        True,
    )


def reference_delay(status: StreamStatus, arrival_s: float) -> float:
    """The delay a message arriving at ``arrival_s`` is compared with [s] (inf before the
    first)."""
    if not math.isfinite(status.min_delay_s):
        return math.inf
    return status.min_delay_s + DRIFT_ALLOWANCE * max(0.0, arrival_s - status.min_delay_t_s)


def stream_condition(status: StreamStatus, t_s: float, timeout_s: float) -> str:
    """``"ok"``, ``"waiting"`` (nothing accepted yet) or ``"timeout"`` at station time ``t_s``."""
    if status.accepted_utime is None:
        return "waiting"
    return "ok" if status.age_s(t_s) <= timeout_s else "timeout"


def note_condition(status: StreamStatus, condition: str) -> StreamStatus:
    """Count a transition from ``ok`` to ``timeout`` (call on every check)."""
    ok = condition == "ok"
    if status.was_ok and condition == "timeout":
        return replace(status, was_ok=False, timeouts=status.timeouts + 1)
    if ok != status.was_ok:
        return replace(status, was_ok=ok)
    return status


@dataclass(frozen=True)
class StationStatus:
    """What the station's ``station_status`` output says: each stream's condition now and its
    counts. The simulated and replay stations report ``ok`` streams with no counts."""

    state: str = "ok"
    """Condition of the state stream (one of :data:`CONDITIONS`)."""
    camera: str = "ok"
    """Condition of the camera stream."""
    streams: tuple[StreamStatus, ...] = ()
    source: str = "sim"
    """Which station: ``"sim"``, ``"lcm"`` or ``"replay"``."""

    @property
    def ok(self) -> bool:
        return self.state == "ok" and self.camera == "ok"

    def reason(self) -> str:
        """One line: ``"ok"`` or what is wrong (``"state timeout (last rejection: late)"``)."""
        parts = []
        by_name = {s.name: s for s in self.streams}
        for name, cond in (("state", self.state), ("camera", self.camera)):
            if cond != "ok":
                last = by_name.get(name)
                why = (
                    f" (last rejection: {last.last_rejection})"
                    if last and last.last_rejection
                    else ""
                )
                parts.append(f"{name} {cond}{why}")
        return "; ".join(parts) if parts else "ok"

    def to_dict(self) -> dict:
        return {
            "source": self.source,
            "state": self.state,
            "camera": self.camera,
            "streams": {s.name: s.to_dict() for s in self.streams},
        }


def require_positive(owner: str, **values: float) -> None:
    """Raise ValueError naming ``owner`` and the first of ``values`` that is not a finite
    number > 0."""
    for name, value in values.items():
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"{owner}: {name} must be a finite number > 0, got {value!r}")


@dataclass(frozen=True)
class StreamLimits:
    """What a receiver accepts from one stream: its timeout, the allowed extra delay, and the
    clock the delay is measured on (the wall clock on hardware, else the station's time)."""

    timeout_s: float
    max_delay_s: float = math.inf
    wall_clock: bool = False

    def __post_init__(self) -> None:
        require_positive("StreamLimits", timeout_s=self.timeout_s)
        if not self.max_delay_s > 0:  # inf: lateness not checked
            raise ValueError(f"StreamLimits: max_delay_s must be > 0, got {self.max_delay_s!r}")

    def check(
        self, status: StreamStatus, t_s: float, utime: int, problem: str = ""
    ) -> tuple[StreamStatus, bool]:
        """:func:`check_message` with these limits."""
        arrival = time.monotonic() if self.wall_clock else None
        return check_message(
            status, t_s, utime, problem=problem, max_delay_s=self.max_delay_s, arrival_s=arrival
        )

    def condition(self, status: StreamStatus, t_s: float) -> str:
        return stream_condition(status, t_s, self.timeout_s)

    def settle(self, status: StreamStatus, t_s: float) -> StreamStatus:
        """``status`` with the transition to ``timeout`` (if any) counted at ``t_s``."""
        return note_condition(status, self.condition(status, t_s))
