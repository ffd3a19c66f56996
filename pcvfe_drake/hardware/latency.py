"""End-to-end latency from a state message to the actuation message computed after it.

The vehicle side (``pcvfe vehicle-bridge``) notes when each state message of its own comes back
from the bus (``note_state``) and when each actuation arrives (``note_actuation``); every
actuation carries the ``utime`` of the newest state the station had accepted, so its latency is
``t_actuation - t_state[state_utime]``, both on the vehicle's wall clock. Only the first
actuation after a given state counts (the one that state caused); the others repeat it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class LatencyRecorder:
    """Wall-clock times [s] of states and actuations; :meth:`summary` gives the statistics."""

    max_states: int = 100_000
    state_wall_s: dict[int, float] = field(default_factory=dict)
    latencies_s: list[float] = field(default_factory=list)
    actuations: int = 0
    unmatched: int = 0
    _answered: set[int] = field(default_factory=set)

    def note_state(self, utime: int, wall_s: float) -> None:
        if len(self.state_wall_s) >= self.max_states:
            self.state_wall_s.pop(next(iter(self.state_wall_s)))
        self.state_wall_s.setdefault(int(utime), float(wall_s))

    def note_actuation(self, state_utime: int, wall_s: float) -> None:
        self.actuations += 1
        state_utime = int(state_utime)
        if state_utime in self._answered:
            return
        sent = self.state_wall_s.get(state_utime)
        if sent is None:
            self.unmatched += 1
            return
        self._answered.add(state_utime)
        self.latencies_s.append(float(wall_s) - sent)

    def summary(self) -> dict:
        """``n``, ``median_ms``, ``p99_ms``, ``max_ms`` (None without samples), ``actuations``,
        ``unmatched`` (actuations whose state was not seen)."""
        lat = np.asarray(self.latencies_s, dtype=float) * 1e3

        def stat(fn) -> float | None:
            return float(fn(lat)) if lat.size else None

        return {
            "n": int(lat.size),
            "median_ms": stat(np.median),
            "p99_ms": stat(lambda a: np.percentile(a, 99)),
            "max_ms": stat(np.max),
            "actuations": self.actuations,
            "unmatched": self.unmatched,
        }


def format_latency(summary: dict) -> str:
    """One line for the terminal."""
    if not summary.get("n"):
        return "latency: no actuation answered a state yet"
    return (
        f"latency state -> actuation: median {summary['median_ms']:.1f} ms, "
        f"p99 {summary['p99_ms']:.1f} ms, max {summary['max_ms']:.1f} ms "
        f"({summary['n']} states answered, {summary['actuations']} actuations)"
    )
