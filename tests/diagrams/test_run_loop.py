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
from pcvfe_drake.runs.drivelog import read_drive_log


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
    course = load_course(scenario.course)
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
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


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
