"""The control loop's real-time priority from the command line: a priority the OS refuses, or an
invalid one, stops `pcvfe simulate --hardware` and `pcvfe vehicle-bridge` at start-up with one
line naming the setting (exit 2), before anything is written or started. The OS's refusal is
mocked, so these tests pass with or without root."""

from __future__ import annotations

import errno
import os

import pytest

from pcvfe_drake.cli import main


def _error(capsys, argv) -> str:
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 2, captured
    assert "Traceback" not in captured.err
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    return lines[0]


@pytest.fixture
def eperm(monkeypatch):
    """sched_setscheduler refuses as for a user without CAP_SYS_NICE or an rtprio limit."""
    calls = []

    def refuse(pid, policy, param):
        calls.append(param.sched_priority)
        raise PermissionError(errno.EPERM, os.strerror(errno.EPERM))

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    return calls


def _priority_overlay(tmp_path, value) -> str:
    path = tmp_path / "priority.yaml"
    path.write_text(f"hardware:\n  control_priority: {value}\n")
    return str(path)


def test_simulate_hardware_stops_when_the_os_refuses_the_priority(tmp_path, capsys, eperm):
    out = tmp_path / "run"
    argv = ["simulate", "paper_sim", "--with", _priority_overlay(tmp_path, 10), "--hardware"]
    err = _error(capsys, [*argv, "--no-meshcat", "--no-progress", "--out", str(out)])
    assert err.startswith("pcvfe simulate: error: hardware.control_priority=10: the OS refused")
    for hint in ("EPERM", "CAP_SYS_NICE", "rtprio", "set it to 0"):
        assert hint in err, err
    assert eperm == [10]
    assert not out.exists()  # stopped before the run folder


def test_simulate_without_hardware_leaves_the_priority_alone(tmp_path, eperm, monkeypatch):
    """The setting is the LCM station's: a simulation does not apply it (and is not refused)."""
    seen = {}

    def run_simulation(*args, **kwargs):
        seen.update(kwargs)
        raise ValueError("stop here")

    monkeypatch.setattr("pcvfe_drake.diagrams.run_simulation.run_simulation", run_simulation)
    argv = ["simulate", "paper_sim", "--with", _priority_overlay(tmp_path, 10), "--no-meshcat"]
    assert main([*argv, "--no-progress", "--out", str(tmp_path / "run")]) == 2
    assert seen["control_priority"] == 0 and eperm == []


def test_an_invalid_priority_is_named(tmp_path, capsys):
    argv = ["simulate", "paper_sim", "--with", _priority_overlay(tmp_path, 100), "--hardware"]
    err = _error(capsys, [*argv, "--no-meshcat", "--out", str(tmp_path / "run")])
    assert "hardware.control_priority=100: must be 0-99 (0: off)" in err


def test_vehicle_bridge_stops_when_the_os_refuses_the_priority(tmp_path, capsys, eperm):
    url = "tcpq://127.0.0.1:9"  # never reached: the priority is refused before the hub starts
    err = _error(capsys, ["vehicle-bridge", "--lcm-url", url, "--priority", "20", "--quiet"])
    assert err.startswith("pcvfe vehicle-bridge: error: --priority=20: the OS refused")
    assert "CAP_SYS_NICE" in err and eperm == [20]


@pytest.mark.parametrize("value", ["100", "-1", "high"])
def test_vehicle_bridge_refuses_an_invalid_priority(capsys, value):
    with pytest.raises(SystemExit) as exit_:
        main(["vehicle-bridge", "--priority", value])
    assert exit_.value.code == 2
    assert "--priority" in capsys.readouterr().err
