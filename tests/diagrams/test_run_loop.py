"""The run loop: laps end the run at the row that completes them; Ctrl-C (also when OSQP
catches it), SIGTERM and a full disk stop the run and keep what was logged."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

from pcvfe_drake.control.course import load_course
from pcvfe_drake.control.nmpc import NmpcController
from pcvfe_drake.diagrams import run_simulation as run_module
from pcvfe_drake.diagrams.run_simulation import RunFolder, run_simulation
from pcvfe_drake.diagrams.scenario_io import load_scenario
from pcvfe_drake.diagrams.world_io import scenario_course
from pcvfe_drake.hardware.scheduling import real_time_permitted
from pcvfe_drake.runs.drivelog import read_drive_log
from pcvfe_drake.runs.summary import summary_table


def short(duration_s=None, laps=None):
    s = load_scenario("paper_sim")
    s.start_s_m = 80.0
    return s.with_run_length(duration_s=duration_s, laps=laps)


def test_a_run_by_laps_stops_at_the_row_that_completes_them(tmp_path):
    scenario = short(laps=0.02)  # 17.8 m of the 891 m lap: ~4 s at the start speed
    folder = RunFolder(tmp_path / "run")
    result = run_simulation(scenario, folder, progress=False, chunk_s=1.0)
    s = result.summary
    assert s["stop_reason"] == "laps" and not s["interrupted"]
    log = read_drive_log(folder.drive_log)
    course = scenario_course(scenario)
    progress = course.unwrap_progress(course.project(log[["sx", "sy"]].to_numpy()).s)
    travelled = (progress - progress[0]) / course.length
    first = int(np.argmax(travelled >= 0.02))
    assert travelled[first] >= 0.02 and travelled[first - 1] < 0.02
    # The goal row, then at most the run logger's held-back last row: no overshoot (polling
    # once per 1 s chunk ran up to 20 rows past it).
    assert len(log) - 1 <= first + 1, (len(log), first)
    assert s["laps_fraction"] >= 0.02


def _nmpc_interrupts_after(monkeypatch, updates: int):
    """The NMPC's OSQP solve reports 'interrupted' (Ctrl-C caught by OSQP) after ``updates``."""
    real = NmpcController.step

    def step(self, x, theta, memory):
        if memory.updates >= updates:
            from types import SimpleNamespace

            solver = self._solver

            class Interrupted:
                def __getattr__(self, name):
                    return getattr(solver, name)

                def solve(self, raise_error=False):
                    res = solver.solve(raise_error=raise_error)
                    info = SimpleNamespace(status="interrupted")
                    return SimpleNamespace(x=res.x, y=res.y, info=info)

            self._solver = Interrupted()
            try:
                return real(self, x, theta, memory)
            finally:
                self._solver = solver
        return real(self, x, theta, memory)

    monkeypatch.setattr(NmpcController, "step", step)


def _sigterm_after(monkeypatch, t_s: float):
    """SIGTERM arrives once the simulation is past ``t_s``. A test-only handler is installed
    first, so that without the loop's own handler the run goes on (and the test fails) instead
    of killing pytest."""
    seen = []
    previous = signal.signal(signal.SIGTERM, lambda *a: seen.append("ignored"))

    class Terminated(run_module.Simulator):
        def AdvanceTo(self, t):
            if t > t_s and not seen:
                seen.append("sent")
                os.kill(os.getpid(), signal.SIGTERM)
            return super().AdvanceTo(t)

    monkeypatch.setattr(run_module, "Simulator", Terminated)
    return previous


@pytest.mark.parametrize("how", ["osqp_ctrl_c", "sigterm"])
def test_interrupts_stop_the_run_and_keep_everything(tmp_path, monkeypatch, how):
    previous = None
    sigint_before = signal.getsignal(signal.SIGINT)  # SIG_IGN where started in the background
    if how == "osqp_ctrl_c":
        _nmpc_interrupts_after(monkeypatch, updates=40)  # t = 2.0 s at 20 Hz
    else:
        previous = _sigterm_after(monkeypatch, 2.0)
    try:
        folder = RunFolder(tmp_path / "run")
        result = run_simulation(short(duration_s=10.0), folder, progress=False)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    s = result.summary
    assert s["interrupted"] is True and s["stop_reason"] == "interrupted"
    assert s["sim_time_s"] < 3.5
    assert s["nmpc_fallbacks"] == 0  # the interrupt is not taken for a failed solve
    if how == "sigterm":
        assert s["interrupt_signal"] == "SIGTERM"
    written = json.loads(folder.summary.read_text())
    assert written["interrupted"] is True
    assert len(read_drive_log(folder.drive_log)) == s["log_rows"] >= 40
    assert result.figures["fig5_mu_over_time"]
    assert signal.getsignal(signal.SIGINT) is sigint_before  # restored


def test_a_full_disk_mid_run_names_the_file_and_keeps_the_summary(tmp_path):
    folder = RunFolder(tmp_path / "run")
    folder.root.mkdir()
    os.symlink("/dev/full", folder.drive_log)  # every write: ENOSPC
    result = run_simulation(short(duration_s=10.0), folder, progress=False)
    s = result.summary
    assert s["stop_reason"] == "error"
    assert str(folder.drive_log) in s["error"] and "the disk is full" in s["error"]
    # Stopped at the first chunk it could not write (50 rows); the rows stay in the summary.
    assert 50 <= s["log_rows"] < 60 and s["sim_time_s"] < 3.0
    assert json.loads(folder.summary.read_text())["error"] == s["error"]
    assert result.figures["fig5_mu_over_time"]
    assert any("drive_log.csv" in e for e in result.write_errors)


def test_the_lap_monitor_stops_at_the_goal_row_with_few_projections():
    """Fed a log row by row (as the run logger writes it), the monitor terminates exactly at the
    first row whose progress reaches the goal, projecting rows in batches far from it."""
    from pydrake.systems.framework import EventStatus
    from pydrake.systems.primitives import ConstantVectorSource

    from pcvfe_drake.diagrams.run_simulation import LapMonitor
    from pcvfe_drake.runs.runlog import RunLog

    course = load_course("slalom")
    run_log = RunLog(None, ["a"], 1)
    system = ConstantVectorSource([0.0])
    dt, v = 0.05, 6.0
    monitor = LapMonitor(
        system, course, run_log, 0.1, log_period_s=dt, v_max_mps=50.0, a_max_mps2=11.5
    )
    calls = []
    update = monitor.progress.update
    monitor.progress.update = lambda xy: calls.append(len(xy)) or update(xy)
    s_start = 100.0
    for k in range(2000):
        s = s_start + v * dt * k
        x, y, _, _ = course.sample(np.array([s]))
        state = np.zeros(7)
        state[0], state[1], state[3] = x[0], y[0], v
        run_log.append(k * dt, state, np.zeros(2), np.zeros(1), 0, np.ones(3), 1.0, 0)
        status = monitor(None)
        if status.severity() == EventStatus.Severity.kReachedTermination:
            break
    goal_row = int(np.ceil(0.1 * course.length / (v * dt) - 1e-9))
    assert abs(k - goal_row) <= 1  # the sampled path is a chord shorter or longer by a hair
    progress = course.unwrap_progress(
        course.project(np.array([[r[1], r[2]] for r in run_log.rows_since(0)])).s
    )
    travelled = progress - progress[0]
    assert travelled[-1] >= 0.1 * course.length > travelled[-2]  # stopped at the goal row
    assert sum(calls) == len(run_log) and len(calls) < len(run_log) / 8


def test_an_interrupt_while_the_outputs_are_written_is_held_back(tmp_path, monkeypatch):
    """SIGTERM (or Ctrl-C) while summary and figures are written waits until they are."""
    real = run_module.write_run_outputs

    def write_with_a_signal(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        return real(*args, **kwargs)

    monkeypatch.setattr(run_module, "write_run_outputs", write_with_a_signal)
    previous = signal.signal(signal.SIGTERM, lambda *a: None)  # a safety net for pytest
    try:
        folder = RunFolder(tmp_path / "run")
        result = run_simulation(short(duration_s=1.0), folder, progress=False)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert result.held_signals == ["SIGTERM"]
    assert json.loads(folder.summary.read_text())["stop_reason"] == "duration"
    assert result.figures["fig5_mu_over_time"]


def test_a_car_braked_into_reverse_on_the_multibody_truth_is_a_scored_failure(
    tmp_path, monkeypatch
):
    """The multi-body truth cannot be integrated once a wheel's ground speed is <= 0 (the car
    reverses): the run ends as the catastrophic failure ``truth_singular``, not as an error."""
    scenario = load_scenario("paper_sim_mb").with_run_length(duration_s=5.0)
    scenario.estimator = "oracle"
    scenario.initial_speed_mps = 0.5
    real = NmpcController.step

    def full_brake(self, x, theta, memory):
        _, memory, diagnostics = real(self, x, theta, memory)
        return np.array([0.0, -self.params.a_max]), memory, diagnostics

    monkeypatch.setattr(NmpcController, "step", full_brake)
    folder = RunFolder(tmp_path / "run")
    result = run_simulation(scenario, folder, progress=False, debug_layers=False)
    s = result.summary
    assert "error" not in s and s["stop_reason"] == "failure"
    assert s["catastrophic_failures"] == len(s["failure_events"]) >= 1
    last = s["failure_events"][-1]
    assert last["kind"] == "truth_singular" and "reversing" in last["detail"]
    assert 0.0 < last["t_s"] < 2.0 and last["sx_m"] is not None
    assert json.loads(folder.summary.read_text())["failure_events"][-1] == last
    assert "truth model singular" in summary_table(s)


@pytest.mark.skipif(
    not real_time_permitted(),
    reason="SCHED_FIFO not permitted here (no root, CAP_SYS_NICE, rtprio)",
)
def test_the_control_priority_holds_for_the_loop_thread_only_while_it_runs(tmp_path, monkeypatch):
    """``control_priority`` raises the thread that runs the loop (the NMPC's updates run on it at
    SCHED_FIFO) and drops it before the outputs are written (best-effort work)."""
    import threading

    def policy():
        flag = os.SCHED_RESET_ON_FORK
        return os.sched_getscheduler(0) & ~flag, os.sched_getparam(0).sched_priority

    seen = {"nmpc": set(), "outputs": None}
    real_step, real_write = NmpcController.step, run_module.write_run_outputs

    def step(self, x, theta, memory):
        seen["nmpc"].add((threading.get_native_id(), *policy()))
        return real_step(self, x, theta, memory)

    def write_run_outputs(*args, **kwargs):
        seen["outputs"] = policy()
        return real_write(*args, **kwargs)

    monkeypatch.setattr(NmpcController, "step", step)
    monkeypatch.setattr(run_module, "write_run_outputs", write_run_outputs)
    before = policy()
    folder = RunFolder(tmp_path / "run")
    run_simulation(short(duration_s=0.5), folder, progress=False, control_priority=4)
    assert seen["nmpc"] == {(threading.get_native_id(), os.SCHED_FIFO, 4)}
    assert seen["outputs"] == before == policy()


def test_the_objects_built_before_the_loop_are_frozen_for_the_loop_only(tmp_path, monkeypatch):
    """The loop runs with what was built before it frozen out of the cyclic collector (its
    full passes would walk the diagram and the modules again), and unfreezes it before the
    outputs are written."""
    import gc

    seen = {"nmpc": set(), "outputs": None}
    real_step, real_write = NmpcController.step, run_module.write_run_outputs

    def step(self, x, theta, memory):
        seen["nmpc"].add(gc.get_freeze_count() > 0)
        return real_step(self, x, theta, memory)

    def write_run_outputs(*args, **kwargs):
        seen["outputs"] = gc.get_freeze_count()
        return real_write(*args, **kwargs)

    monkeypatch.setattr(NmpcController, "step", step)
    monkeypatch.setattr(run_module, "write_run_outputs", write_run_outputs)
    assert gc.get_freeze_count() == 0
    run_simulation(short(duration_s=0.5), RunFolder(tmp_path / "run"), progress=False)
    assert seen == {"nmpc": {True}, "outputs": 0} and gc.get_freeze_count() == 0


def test_the_first_monitor_that_ends_the_run_wins():
    from pydrake.systems.framework import EventStatus

    calls = []

    def watching(name, status):
        def m(context):
            calls.append(name)
            return status

        return m

    quiet = watching("quiet", EventStatus.Succeeded())
    assert run_module._first_termination([quiet]) is quiet  # called by the simulator directly
    ends = EventStatus.Severity.kReachedTermination
    both = run_module._first_termination(
        [quiet, watching("ends", EventStatus.ReachedTermination(None, "goal")), quiet]
    )
    assert both(None).severity() == ends and calls == ["quiet", "ends"]
    calm = run_module._first_termination([quiet, quiet])
    assert calm(None).severity() == EventStatus.Severity.kSucceeded


def test_the_first_step_s_one_off_costs_are_paid_before_the_loop(tmp_path, monkeypatch):
    """``run_simulation`` warms the diagram up (``diagrams/warm_up.py``) once, before the
    simulator is initialized: the loop's CPU time counts its steady cost, not the compiled
    model's loading."""
    from pydrake.systems.analysis import Simulator

    calls = []
    real_warm_up = run_module.warm_up
    real_initialize = Simulator.Initialize

    def warm_up(diagram):
        calls.append("warm_up")
        return real_warm_up(diagram)

    def initialize(self, *args):
        calls.append("initialize")
        return real_initialize(self, *args)

    monkeypatch.setattr(run_module, "warm_up", warm_up)
    monkeypatch.setattr(Simulator, "Initialize", initialize)
    run_simulation(short(duration_s=0.2), RunFolder(tmp_path / "run"), progress=False)
    assert calls == ["warm_up", "initialize"]
