"""The control loop's real-time priority (core, no pydrake): validation, the OS's refusals as one
line naming the setting, and, where this machine permits SCHED_FIFO, the thread it applies to."""

from __future__ import annotations

import errno
import os
import sys
import threading

import pytest

from pcvfe_drake.hardware.scheduling import (
    SchedulingError,
    check_control_priority,
    control_priority,
    normal_scheduling,
    priority_problem,
    real_time_permitted,
)
from pcvfe_drake.hardware.settings import HardwareSettings, hardware_problems

SETTING = "hardware.control_priority"


needs_fifo = pytest.mark.skipif(
    not real_time_permitted(),
    reason="SCHED_FIFO not permitted here (no root, CAP_SYS_NICE, rtprio)",
)


@pytest.mark.parametrize("value", [0, 1, 50, 99])
def test_priorities_0_to_99_are_valid(value):
    assert priority_problem(value, SETTING) is None
    assert hardware_problems(HardwareSettings(control_priority=value)) == []


@pytest.mark.parametrize("value", [-1, 100, 2.5, True, "10", None])
def test_a_bad_priority_is_named_in_the_hardware_settings(value):
    problems = hardware_problems(HardwareSettings(control_priority=value))
    assert len(problems) == 1 and problems[0].startswith(f"{SETTING}={value!r}: must be")
    assert "0-99" in problems[0]


def refuse(monkeypatch, code: int) -> list:
    calls = []

    def sched_setscheduler(pid, policy, param):
        calls.append((pid, policy, param.sched_priority))
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(os, "sched_setscheduler", sched_setscheduler, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setattr(os, "sched_getscheduler", lambda pid: 0, raising=False)
    monkeypatch.setattr(os, "sched_getparam", lambda pid: os.sched_param(0), raising=False)
    return calls


def test_eperm_is_one_line_naming_the_setting_and_how_to_grant_it(monkeypatch):
    calls = refuse(monkeypatch, errno.EPERM)
    with pytest.raises(SchedulingError) as err:
        check_control_priority(10, SETTING)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{SETTING}=10: the OS refused real-time priority SCHED_FIFO 10")
    for hint in ("EPERM", "root", "CAP_SYS_NICE", "rtprio", "limits.conf", "set it to 0"):
        assert hint in message, message
    # The calling thread (pid 0), not the process; what it starts begins at ordinary scheduling.
    assert calls == [(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, 10)]


def test_another_refusal_names_the_os_reason(monkeypatch):
    refuse(monkeypatch, errno.EINVAL)
    with pytest.raises(SchedulingError, match=r"--priority=5: .*Invalid argument.*set it to 0"):
        check_control_priority(5, "--priority")


def test_not_linux_is_refused_with_the_setting(monkeypatch):
    calls = refuse(monkeypatch, errno.EPERM)
    monkeypatch.setattr(sys, "platform", "darwin")
    with pytest.raises(
        SchedulingError, match=rf"^{SETTING}=10: .*need Linux.*darwin; set it to 0$"
    ):
        check_control_priority(10, SETTING)
    monkeypatch.delattr(os, "sched_setscheduler")
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(SchedulingError, match="need Linux"):
        check_control_priority(10, SETTING)
    assert calls == []


def test_zero_changes_nothing_and_a_bad_value_is_refused_before_the_os(monkeypatch):
    calls = refuse(monkeypatch, errno.EPERM)
    with control_priority(0, SETTING):
        pass
    with pytest.raises(SchedulingError, match=rf"{SETTING}=100: must be 0-99"):
        check_control_priority(100, SETTING)
    assert calls == []


def policy(tid: int = 0) -> tuple[int, int]:
    """(policy without the SCHED_RESET_ON_FORK flag, priority) of a thread (0: this one)."""
    flag = os.SCHED_RESET_ON_FORK
    return os.sched_getscheduler(tid) & ~flag, os.sched_getparam(tid).sched_priority


@needs_fifo
@pytest.mark.parametrize("children_inherit", [False, True])
def test_the_priority_is_the_calling_threads_and_threads_it_starts_drop_it(children_inherit):
    before = policy()
    seen = {}

    def started():
        seen["started"] = policy()

    def worker():
        normal_scheduling()
        seen["worker"] = policy()

    def other():
        seen["other_during"] = policy()

    # A thread started before the block keeps its policy while the block runs.
    gate = threading.Event()
    bystander = threading.Thread(target=lambda: (gate.wait(5), other()))
    bystander.start()
    with control_priority(7, SETTING, children_inherit=children_inherit):
        seen["loop"] = policy()
        seen["loop_by_tid"] = policy(threading.get_native_id())
        gate.set()
        bystander.join()
        for target in (started, worker):
            t = threading.Thread(target=target)
            t.start()
            t.join()
    assert seen["loop"] == seen["loop_by_tid"] == (os.SCHED_FIFO, 7)
    assert seen["other_during"] == before
    # SCHED_RESET_ON_FORK: what the loop starts begins at ordinary scheduling; the bridge's hub
    # inherits (children_inherit), and a worker drops it itself (normal_scheduling).
    assert seen["started"] == ((os.SCHED_FIFO, 7) if children_inherit else (os.SCHED_OTHER, 0))
    assert seen["worker"] == (os.SCHED_OTHER, 0)
    assert policy() == before  # restored after the block
    normal_scheduling()  # on an ordinary thread: nothing to do
    assert policy() == before
