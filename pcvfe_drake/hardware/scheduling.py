"""A real-time scheduling priority for the control loop's thread (Linux ``SCHED_FIFO``).

A control loop on a car's computer does not share a core on equal terms with best-effort work:
a thread at a ``SCHED_FIFO`` priority runs whenever it is ready, before every ordinary
(``SCHED_OTHER``) thread, so a competing process can no longer delay a state's answer by a
scheduler time slice. The loop sleeps while it is ahead of the wall clock (Drake's paced
simulator, the receivers' bounded waits), so the core is free between its steps, and Linux's
real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``) keeps a share of each core for
ordinary threads should it not.

Only the loop's thread is raised. A thread inherits its creator's policy, so the loop's policy
carries ``SCHED_RESET_ON_FORK``: the threads and processes it starts (the context fitter's
refit worker, a library's helper threads) begin at ``SCHED_OTHER``, and a refit never preempts
the loop. The refit worker also sets itself back with :func:`normal_scheduling`, for a loop
raised from outside (``chrt -f 10 pcvfe simulate ...`` raises every thread). Core module (no
pydrake).
"""

from __future__ import annotations

import errno
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

PRIORITY_MAX = 99
"""Highest ``SCHED_FIFO`` priority on Linux (``sched_get_priority_max``)."""

GRANT_HINT = (
    "run as root, give the interpreter CAP_SYS_NICE (setcap cap_sys_nice+ep), or raise the "
    "user's rtprio limit (/etc/security/limits.conf: USER - rtprio N; see docs/hardware.md)"
)
"""How to allow a real-time priority, for the errors below."""


class SchedulingError(ValueError):
    """The OS refused a real-time priority (a one-line message naming the setting)."""


def priority_problem(priority: object, setting: str) -> str | None:
    """Why ``priority`` is not a valid priority for ``setting`` (None: valid): an integer in
    0..:data:`PRIORITY_MAX`, 0 meaning ordinary scheduling."""
    if isinstance(priority, bool) or not isinstance(priority, int):
        return f"{setting}={priority!r}: must be an integer 0-{PRIORITY_MAX} (0: off)"
    if not 0 <= priority <= PRIORITY_MAX:
        return f"{setting}={priority!r}: must be 0-{PRIORITY_MAX} (0: off)"
    return None


def _refusal(priority: int, setting: str, exc: OSError) -> SchedulingError:
    if exc.errno == errno.EPERM:
        return SchedulingError(
            f"{setting}={priority}: the OS refused real-time priority SCHED_FIFO {priority} "
            f"(EPERM: not permitted); {GRANT_HINT}, or set it to 0"
        )
    return SchedulingError(
        f"{setting}={priority}: the OS refused real-time priority SCHED_FIFO {priority} "
        f"({os.strerror(exc.errno) if exc.errno else exc}); set it to 0"
    )


@contextmanager
def control_priority(
    priority: int, setting: str, *, children_inherit: bool = False
) -> Iterator[None]:
    """Run the calling thread at ``SCHED_FIFO`` ``priority`` inside the block and restore its
    previous policy afterwards; 0 changes nothing. Threads and processes it starts meanwhile
    begin at ordinary scheduling (``SCHED_RESET_ON_FORK``) unless ``children_inherit`` (the
    vehicle bridge's local hub, the network's stand-in in a rehearsal, inherits the bridge's).
    Raises :class:`SchedulingError` (one line naming ``setting`` and what to do) where the OS
    refuses it (no root, no CAP_SYS_NICE, an rtprio limit below ``priority``) or has no such
    scheduling (not Linux)."""
    problem = priority_problem(priority, setting)
    if problem:
        raise SchedulingError(problem)
    if priority == 0:
        yield
        return
    if not sys.platform.startswith("linux") or not hasattr(os, "sched_setscheduler"):
        raise SchedulingError(
            f"{setting}={priority}: real-time priorities need Linux (os.sched_setscheduler), "
            f"not {sys.platform}; set it to 0"
        )
    # pid 0 is the calling thread, not the whole process: Linux schedules threads.
    before = (os.sched_getscheduler(0), os.sched_getparam(0))
    policy = os.SCHED_FIFO if children_inherit else os.SCHED_FIFO | os.SCHED_RESET_ON_FORK
    try:
        os.sched_setscheduler(0, policy, os.sched_param(priority))
    except OSError as exc:
        raise _refusal(priority, setting, exc) from None
    try:
        yield
    finally:
        os.sched_setscheduler(0, *before)  # lowering one's own priority is always allowed


def check_control_priority(priority: int, setting: str) -> None:
    """Raise :class:`SchedulingError` now, at start-up, if :func:`control_priority` would."""
    with control_priority(priority, setting):
        pass


def real_time_permitted(priority: int = 1) -> bool:
    """Whether this process may run a thread at ``SCHED_FIFO`` ``priority`` (root,
    CAP_SYS_NICE or an rtprio limit, on Linux): a check that changes nothing."""
    try:
        check_control_priority(priority, "real-time priority")
    except SchedulingError:
        return False
    return True


def normal_scheduling() -> None:
    """Set the calling thread back to ``SCHED_OTHER`` if it inherited a real-time policy (the
    initializer of threads that a real-time loop starts, such as the refit worker)."""
    if not hasattr(os, "sched_getscheduler"):
        return
    realtime = {getattr(os, name) for name in ("SCHED_FIFO", "SCHED_RR") if hasattr(os, name)}
    if (os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)) in realtime:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
