"""Progress of a long loop: a tqdm bar on a terminal, a plain line every few percent elsewhere.

A bar redraws itself with carriage returns many times a second; written to a log file or a CI
console (no terminal), that is thousands of updates in one line. :func:`progress_bar` therefore
returns tqdm's bar only when its stream is a terminal, and otherwise a :class:`LineProgress`
with the same small interface (iterate, ``update``, ``n``, ``set_postfix_str``, ``write``,
``close``, ``with``) that prints one line each time the count crosses the next
``every_percent`` step (or, without a known total, at most every ``every_s`` seconds).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any, TextIO


def _interactive(stream: TextIO) -> bool:
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # a closed stream
        return False


def _clock(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class LineProgress:
    """Progress as whole lines: ``desc: 35 % (7/20 run), 1:12 elapsed, ~2:14 left, postfix``."""

    def __init__(
        self,
        iterable: Iterable | None = None,
        *,
        total: float | None = None,
        desc: str = "",
        unit: str = "it",
        stream: TextIO | None = None,
        every_percent: float = 5.0,
        every_s: float = 30.0,
    ) -> None:
        if not every_percent > 0:
            raise ValueError(f"every_percent must be > 0, got {every_percent}")
        self.iterable = iterable
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        self.total = total
        self.desc = desc
        self.unit = unit
        self.stream = sys.stderr if stream is None else stream
        self.every_percent = float(every_percent)
        self.every_s = float(every_s)
        self.n: float = 0
        self.postfix = ""
        self._t0 = time.monotonic()
        self._last_step = 0  # the last every_percent step printed
        self._last_print = self._t0
        self._printed_n: float | None = None  # the count of the last line printed
        self._closed = False

    def __iter__(self) -> Iterator:
        if self.iterable is None:
            raise TypeError("LineProgress: no iterable given")
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _line(self) -> str:
        elapsed = time.monotonic() - self._t0
        head = f"{self.desc}: " if self.desc else ""
        if self.total:
            share = self.n / self.total
            text = f"{head}{100 * share:.0f} % ({self.n:.0f}/{self.total:.0f} {self.unit})"
            text += f", {_clock(elapsed)} elapsed"
            if 0 < share < 1:
                text += f", ~{_clock(elapsed * (1 - share) / share)} left"
        else:
            text = f"{head}{self.n:.0f} {self.unit}, {_clock(elapsed)} elapsed"
        return text + (f", {self.postfix}" if self.postfix else "")

    def _print(self) -> None:
        print(self._line(), file=self.stream, flush=True)
        self._last_print = time.monotonic()
        self._printed_n = self.n

    def update(self, n: float = 1) -> None:
        """Count ``n`` more; print a line when the next step (or ``every_s``) is reached."""
        self.n += n
        if self.total:
            step = math.floor(100 * self.n / self.total / self.every_percent + 1e-9)
            if step > self._last_step:
                self._last_step = step
                self._print()
        elif time.monotonic() - self._last_print >= self.every_s:
            self._print()

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        """Text appended to the next line printed (``refresh`` is accepted for tqdm's sake)."""
        self.postfix = s

    def write(self, s: str) -> None:
        """Print a message on its own line."""
        print(s, file=self.stream, flush=True)

    def close(self) -> None:
        """Print the final line unless the last update already printed it."""
        if self._closed:
            return
        self._closed = True
        if self._printed_n != self.n:
            self._print()


def progress_bar(
    iterable: Iterable | None = None,
    *,
    total: float | None = None,
    desc: str = "",
    unit: str = "it",
    stream: TextIO | None = None,
    every_percent: float = 5.0,
    **tqdm_options: Any,
):
    """tqdm's bar on ``stream`` (default stderr) when it is a terminal, else a
    :class:`LineProgress` printing a line every ``every_percent`` percent. ``tqdm_options``
    (``bar_format``, ``smoothing``, ...) only concern the bar."""
    stream = sys.stderr if stream is None else stream
    if _interactive(stream):
        from tqdm import tqdm

        options = {"desc": desc or None, "unit": unit, "file": stream, **tqdm_options}
        return tqdm(iterable, total=total, **options)
    return LineProgress(
        iterable, total=total, desc=desc, unit=unit, stream=stream, every_percent=every_percent
    )
