"""Running a scenario end to end: the simulation loop (the run folder is written by the core).

:func:`run_simulation` builds ``MakeSimulation``, applies the scenario's ``simulator`` settings
(Drake's ``SimulatorConfig`` through ``ApplySimulatorConfig``), and advances the simulator in
chunks of simulated time for the progress bar (simulated time, real-time factor, laps, context).
It stops

- at ``scenario.duration_s`` (``AdvanceTo`` the exact time), or
- when ``scenario.laps`` laps are done: a ``Simulator.set_monitor`` monitor (:class:`LapMonitor`)
  follows the drive log's rows as they are written and ends ``AdvanceTo`` at the step that
  writes the row completing the goal (the same rows and course projection the summary counts
  laps with, so the run never overshoots and the summary agrees), at ``max_duration_s`` at the
  latest, or
- with ``scenario.stop_on_failure``, at the first catastrophic failure of the true state
  (:class:`FailureMonitor`, checked every second of rows; ``summary["stop_reason"]`` is
  ``"failure"`` and ``summary["failure_events"]`` says when, where and why), or
- at Ctrl-C or SIGTERM (``summary["interrupted"]``, ``summary["interrupt_signal"]``; an
  interrupt that OSQP catches during a solve is raised again by the NMPC), or
- when the simulated truth can no longer be integrated (the multi-body model's singularity: a
  wheel's ground speed <= 0, the car reverses or has spun; ``MbSingularity``): scored as the
  catastrophic failure ``truth_singular`` (``pcvfe_drake.control.failure``), the run's last
  entry in ``summary["failure_events"]``, ``summary["stop_reason"]`` ``"failure"``, or
- when the simulation raises (``summary["error"]``), the drive log's disk included.

On every ending it closes the drive log, stops the Meshcat recording and hands the data to
``pcvfe_drake.runs.run_folder.write_run_outputs`` (Drake-free), which writes ``playback.html``,
the figures and ``summary.json``. While those are written, Ctrl-C and SIGTERM are held back (the
writer finishes; the interrupt is noted in the summary).
"""

from __future__ import annotations

import dataclasses
import gc
import signal
import threading
import time
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import (
    ApplySimulatorConfig,
    GetIntegrationSchemes,
    Simulator,
    SimulatorConfig,
    SimulatorStatus,
)
from pydrake.systems.framework import Diagram, EventStatus

from pcvfe_drake.control import failure
from pcvfe_drake.control.course import Course
from pcvfe_drake.diagrams.debug_layers import LAYERS
from pcvfe_drake.diagrams.meshcat_controls import MeshcatControls
from pcvfe_drake.diagrams.release import release_diagram
from pcvfe_drake.diagrams.simulation import MakeSimulation, course_xy
from pcvfe_drake.diagrams.warm_up import warm_up
from pcvfe_drake.hardware import scheduling
from pcvfe_drake.runs.run_folder import (
    RunFolder,
    RunRecord,
    SimulationResult,
    write_run_outputs,
)
from pcvfe_drake.runs.runlog import TRUE_STATE_COLUMNS, RunLog, feature_columns
from pcvfe_drake.runs.scenario import Scenario
from pcvfe_drake.vehicle.mb_truth import MbSingularity
from pcvfe_drake.vehicle.single_track import BETA, PSI, STATE_NAMES, SX, SY

__all__ = [
    "LapMonitor",
    "LapProgress",
    "RunFolder",
    "SimulationResult",
    "StartLocalMeshcat",
    "run_simulation",
    "simulator_config",
]


class LapProgress:
    """Progress along the course [m] from a stream of positions (wrap-around aware): the same
    projection and unwrapping as the summary's lap count
    (``pcvfe_drake.runs.summary.course_tracking``)."""

    def __init__(self, course: Course) -> None:
        self.course = course
        self._s_prev: float | None = None
        self.travelled_m = 0.0

    def update(self, xy: np.ndarray) -> float:
        """Feed new positions (N, 2) in time order; returns laps travelled so far."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if len(xy):
            s = np.asarray(self.course.project(xy).s, dtype=float).reshape(-1)
            if self._s_prev is not None:
                s = np.concatenate([[self._s_prev], s])
            if len(s) > 1:
                self.travelled_m += float(self.course.unwrap_progress(s)[-1] - s[0])
            self._s_prev = float(s[-1])
        return self.travelled_m / self.course.length

    @property
    def laps(self) -> float:
        return self.travelled_m / self.course.length


class LapMonitor:
    """``Simulator.set_monitor`` callback: ends ``AdvanceTo`` when the drive log's rows have
    covered ``laps_goal`` laps.

    It looks at the run log after every step and projects the new rows onto the course (one
    call for all of them) once there are as many as the car needs at least to reach the goal,
    at most ``batch_rows``: the distance left divided by the farthest the car can get per row
    (the fastest speed so far, from ``v_start_mps`` and the logged rows, plus ``a_max_mps2`` for
    a batch's duration, capped at
    ``v_max_mps``, with a 1.5 margin). Far from the goal that is one projection per batch; near
    it the waits halve, down to single rows. The run stops at the step that writes the row
    reaching the goal, for about one projection per simulated second.
    """

    def __init__(
        self,
        system,
        course: Course,
        run_log: RunLog,
        laps_goal: float,
        *,
        log_period_s: float,
        v_max_mps: float,
        a_max_mps2: float,
        v_start_mps: float = 0.0,
        batch_rows: int = 20,
    ) -> None:
        self.system = system
        self.run_log = run_log
        self.goal_m = float(laps_goal) * course.length
        self.progress = LapProgress(course)
        self.rows_seen = 0
        self.batch_rows = int(batch_rows)
        self.batch_s = self.batch_rows * float(log_period_s)
        self.v_max_mps = abs(float(v_max_mps))
        self.a_max_mps2 = abs(float(a_max_mps2))
        self.v_seen_mps = abs(float(v_start_mps))
        self.reached = False
        columns = run_log.columns
        self._columns = (columns.index("sx"), columns.index("sy"), columns.index("v"))
        self.log_period_s = float(log_period_s)
        self._nothing = EventStatus.DidNothing()
        self._wait_rows = self._rows_needed()

    def _rows_needed(self) -> int:
        """Rows to wait for before the next projection (1 .. batch_rows): fewer rows cannot
        reach the goal."""
        v = min(self.v_max_mps, self.v_seen_mps + self.a_max_mps2 * self.batch_s)
        per_row_m = 1.5 * max(v, 0.1) * self.log_period_s
        left_m = self.goal_m - self.progress.travelled_m - 1.0
        return int(min(self.batch_rows, max(1.0, left_m // per_row_m)))

    def __call__(self, context) -> EventStatus:
        if len(self.run_log) - self.rows_seen < self._wait_rows:
            return self._nothing
        ix, iy, iv = self._columns
        rows = self.run_log.rows_since(self.rows_seen)
        self.rows_seen += len(rows)
        self.progress.update(np.array([[r[ix], r[iy]] for r in rows]))
        speeds = [abs(r[iv]) for r in rows if np.isfinite(r[iv])]
        self.v_seen_mps = max([self.v_seen_mps, *speeds])
        self._wait_rows = self._rows_needed()
        if self.progress.travelled_m >= self.goal_m - 1e-9 * max(self.goal_m, 1.0):
            self.reached = True
            return EventStatus.ReachedTermination(self.system, "lap goal reached")
        return EventStatus.Succeeded()


class FailureMonitor:
    """``Simulator.set_monitor`` callback: ends ``AdvanceTo`` at the first catastrophic failure
    (``pcvfe_drake.control.failure``) in the drive log's rows, checked on the true state where
    the log has it (else the state), every ``batch_rows`` rows (1 s at 20 Hz). ``failure``
    then holds its description (time, place, reason)."""

    def __init__(self, system, course: Course, run_log: RunLog, *, batch_rows: int = 20) -> None:
        self.system = system
        self.course = course
        self.run_log = run_log
        self.batch_rows = int(batch_rows)
        self.rows_seen = 0
        columns = run_log.columns
        self._state = [columns.index(n) for n in STATE_NAMES]
        self._truth = [columns.index(n) for n in TRUE_STATE_COLUMNS if n in columns]
        self._t = columns.index("t")
        self.failure = ""
        self._nothing = EventStatus.DidNothing()

    def states(self, rows: list[list]) -> np.ndarray:
        """(N, 7) states of the rows: the true state, or the state where a row has no truth."""
        x = np.array([[r[c] for c in self._state] for r in rows], dtype=float).reshape(-1, 7)
        if len(self._truth) == 7 and len(rows):
            xt = np.array([[r[c] for c in self._truth] for r in rows], dtype=float)
            has = np.all(np.isfinite(xt), axis=1)
            x[has] = xt[has]
        return x

    def __call__(self, context) -> EventStatus:
        if self.failure or len(self.run_log) - self.rows_seen < self.batch_rows:
            return self._nothing
        rows = self.run_log.rows_since(self.rows_seen)
        self.rows_seen += len(rows)
        x = self.states(rows)
        finite = np.all(np.isfinite(x), axis=1)
        lat = np.full(len(x), np.nan)
        cae = np.zeros(len(x))
        if finite.any():
            pr = self.course.project(x[finite, :2], heading=x[finite, PSI] + x[finite, BETA])
            lat[finite] = pr.lateral_error
            cae[finite] = pr.heading_error
        kinds = failure.failure_kinds(self.course.half_width, lat, cae, x[:, BETA], finite)
        bad = np.flatnonzero(kinds != "")
        if not bad.size:
            return EventStatus.Succeeded()
        i = bad[0]
        self.failure = f"t={rows[i][self._t]:.2f} s at ({x[i, SX]:.1f}, {x[i, SY]:.1f}) m: " + (
            failure.failure_reason(self.course.half_width, lat[i], cae[i], x[i, BETA])
        )
        return EventStatus.ReachedTermination(self.system, "catastrophic failure")


def truth_singular_failure(exc: MbSingularity, course: Course | None, t_s: float) -> dict:
    """The ``failure_events`` entry of a run whose truth became singular (``exc``; its own time,
    else ``t_s``, the simulator's)."""
    x, y = float(exc.state[0]), float(exc.state[1])
    s = float(np.asarray(course.project(np.array([[x, y]])).s).reshape(-1)[0]) if course else np.nan
    t = exc.t_s if np.isfinite(exc.t_s) else t_s
    return failure.truth_singular_event(t, x, y, s, exc.detail).to_dict()


def _first_termination(monitors):
    """One ``set_monitor`` callback from several: the first that ends the run wins (a single
    monitor is returned as it is: the simulator calls it after every step)."""
    if len(monitors) == 1:
        return monitors[0]
    ends = EventStatus.Severity.kReachedTermination
    nothing = EventStatus.DidNothing()

    def monitor(context) -> EventStatus:
        status = nothing
        for m in monitors:
            status = m(context)
            if status.severity() == ends:
                return status
        return status

    return monitor


def simulator_config(scenario: Scenario) -> SimulatorConfig:
    """The scenario's ``simulator`` settings as Drake's ``SimulatorConfig`` (start time 0);
    an unknown integration scheme raises ValueError listing the known ones."""
    settings = scenario.simulator
    schemes = GetIntegrationSchemes()
    if settings.integration_scheme not in schemes:
        raise ValueError(
            f"scenario {scenario.name!r}: simulator.integration_scheme="
            f"{settings.integration_scheme!r} is not one of {schemes}"
        )
    return SimulatorConfig(**dataclasses.asdict(settings))


def StartLocalMeshcat() -> Meshcat:
    """A Meshcat server bound to localhost only (create it once, at the top, and pass it in)."""
    params = MeshcatParams()
    params.host = "localhost"
    return Meshcat(params)


def _estimate_table(diagram, context) -> list[dict]:
    """The fitter's final per-context estimates (id, mu, mu_std, samples, identifiability,
    the effect model's parameters): the table of its estimator with the samples it holds since
    its last decision taken in (``ContextFitter.estimator``)."""
    fitter = diagram.GetSubsystemByName("fitter")
    own = fitter.GetMyContextFromRoot(context)
    table = fitter.estimator(own).table(own.get_time())
    return [
        {
            "id": int(e.context_id),
            "mu": float(e.theta[0]),
            "mu_std": float(e.theta_std[0]),
            "samples": int(e.samples),
            "status": e.status,
            "first_fit_s": float(e.first_fit_s),
            "fits": int(e.fits),
            "mu_lower_bound": float(e.mu_lower_bound),
            "near_limit": bool(e.near_limit),
            "identifiable": bool(e.identifiable),
            "below_used": bool(e.below_used),
            "probe": None if e.probe is None else e.probe.to_dict(),
            "handing": e.handing,
            "mu_interval_95": [float(v) for v in e.mu_interval_95],
            "mu_is_peak": bool(e.mu_is_peak),
            "model_params": {n: float(v) for n, v, _ in e.model_params},
            "sample_to_estimate_s": [float(v) for v in e.sample_to_estimate_s],
            "sample_to_refit_s": [float(v) for v in e.sample_to_refit_s],
        }
        for e in table.entries
        if int(e.context_id) >= 0
    ]


class _Interrupt(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that both end the run the same way."""


@contextmanager
def _signals(mode: str, received: list[str]):
    """Within the block, SIGINT and SIGTERM either raise (``mode="raise"``: SIGTERM as a
    KeyboardInterrupt) or are held back (``"defer"``); each one received is appended to
    ``received``. Outside the main thread nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        name = signal.Signals(signum).name
        received.append(name)
        if mode == "raise":
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            raise _Interrupt(name)

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def run_simulation(
    scenario: Scenario,
    folder: RunFolder | None,
    *,
    meshcat: Meshcat | None = None,
    progress: bool = True,
    chunk_s: float = 1.0,
    write_outputs: bool = True,
    debug_layers: bool = True,
    controls: bool = True,
    station: Diagram | None = None,
    realtime_rate: float | None = None,
    control_priority: int = 0,
) -> SimulationResult:
    """Simulate ``scenario``; write drive log, playback, summary and figures into ``folder``.

    The run stops at ``scenario.duration_s``, or when ``scenario.laps`` laps are completed (at
    ``scenario.max_duration_s`` at the latest), or at Ctrl-C / SIGTERM
    (``summary["interrupted"]``), or when the simulation raises (``summary["error"]``; the
    outputs are still written). ``folder`` must exist or be creatable (the CLI prepares it with
    ``RunFolder.prepare``); write errors after the start are reported, not raised.

    With a ``meshcat``: ``debug_layers`` adds the ``/pcvfe/`` debugging layers
    (``MakeSimulation``), and ``controls`` the Meshcat controls (show/hide layers, pause/resume,
    real-time rate; :class:`pcvfe_drake.diagrams.meshcat_controls.MeshcatControls`), polled
    between chunks of ``chunk_s`` simulated seconds.

    ``station``: another station for ``MakeSimulation`` (the LCM station, a replay station);
    ``realtime_rate``: pace simulated time to this many times wall-clock time (the LCM station
    runs at ``scenario.hardware.realtime_rate``; None: the scenario's simulator settings);
    ``control_priority``: the ``SCHED_FIFO`` priority of the calling thread while the loop runs
    (``hardware.control_priority``, :mod:`pcvfe_drake.hardware.scheduling`; 0: unchanged),
    restored before the outputs are written; raises ``SchedulingError`` before the loop where
    the OS refuses it.
    """
    writing = folder is not None and write_outputs
    if writing:
        folder.root.mkdir(parents=True, exist_ok=True)
    parts = MakeSimulation(
        scenario,
        meshcat,
        log_path=folder.drive_log if writing else None,
        debug_layers=debug_layers,
        station=station,
        refit_worker=realtime_rate is not None,  # paced to the wall clock: refits off the loop
    )
    diagram, course, run_log = parts.diagram, parts.course, parts.run_log
    simulator = Simulator(diagram)
    ApplySimulatorConfig(simulator_config(scenario), simulator)
    if realtime_rate is not None:
        simulator.set_target_realtime_rate(realtime_rate)
    stop_t = scenario.stop_time_s()
    laps_goal = scenario.laps if scenario.duration_s is None else None
    monitor = None
    if laps_goal is not None:
        monitor = LapMonitor(
            diagram,
            course,
            run_log,
            laps_goal,
            log_period_s=scenario.rates.log_period_s,
            v_max_mps=max(abs(parts.params.v_max), abs(parts.params.v_min)),
            a_max_mps2=parts.params.a_max,
            v_start_mps=scenario.initial_speed_mps,
        )
    failure_monitor = None
    if scenario.stop_on_failure:
        failure_monitor = FailureMonitor(diagram, course, run_log)
    monitors = [m for m in (monitor, failure_monitor) if m is not None]
    if monitors:
        simulator.set_monitor(_first_termination(monitors))
    if meshcat is not None:
        meshcat.StartRecording(frames_per_second=1.0 / scenario.rates.view_period_s)
    panel = None
    if meshcat is not None and controls:
        panel = MeshcatControls(
            meshcat,
            LAYERS if debug_layers else (),
            realtime_rate=simulator.get_target_realtime_rate(),
        )
    bar = None
    if progress:
        from pcvfe_drake.progress import progress_bar

        bar = progress_bar(
            total=stop_t,
            unit="s sim",
            bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}{postfix}]",
        )
    received: list[str] = []
    interrupted = False
    error = None
    ending_failure = None
    write_errors: list[str] = []
    stop_reason = "duration" if laps_goal is None else "max_duration"
    wall = 0.0
    cpu = 0.0
    lap_display = LapProgress(course) if bar is not None else None
    rows_shown = 0
    # Raised for the loop only (Initialize's wait for the first message included): the outputs
    # written afterwards are best-effort work. Refused: the error comes before the loop.
    loop_priority = ExitStack()
    loop_priority.enter_context(
        scheduling.control_priority(control_priority, "hardware.control_priority")
    )
    # The first step's one-off costs (the compiled multi-body model's loading or compiling, the
    # first messages) before the loop, not in its clock or its CPU time (diagrams/warm_up.py).
    warm_up(diagram)
    # What exists now (the diagram, its models, the imported modules: some hundred thousand
    # objects) lives through the loop: frozen, the cyclic collector's full passes during the
    # loop skip it instead of walking all of it again. Unfrozen when the loop ends.
    gc.freeze()
    loop_priority.callback(gc.unfreeze)
    try:
        with _signals("raise", received):
            simulator.Initialize()
            # Pace from here: the LCM station's initialization may have waited for the
            # vehicle's first message, and catching up on that wait would run ahead of them.
            simulator.ResetStatistics()
            t = 0.0
            while t < stop_t - 1e-9:
                if panel is not None:
                    panel.poll(simulator)
                target = min(t + chunk_s, stop_t)
                w0, c0 = time.perf_counter(), time.process_time()
                status = simulator.AdvanceTo(target)
                wall += time.perf_counter() - w0
                cpu += time.process_time() - c0
                t = simulator.get_context().get_time()
                if bar is not None:
                    rows = run_log.rows_since(rows_shown)
                    rows_shown += len(rows)
                    laps = lap_display.update(np.array([[r[1], r[2]] for r in rows]))
                    bar.update(t - bar.n)
                    ctx = int(rows[-1][run_log.columns.index("context")]) if rows else -1
                    bar.set_postfix_str(
                        f"t={t:.0f}s rtf={t / max(wall, 1e-9):.1f}x laps={laps:.2f} ctx={ctx}"
                    )
                if status.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition:
                    stop_reason = (
                        "failure" if failure_monitor and failure_monitor.failure else "laps"
                    )
                    break
    except KeyboardInterrupt:
        interrupted = True
        stop_reason = "interrupted"
    except MbSingularity as exc:  # the truth's own end: a scored failure, not an error
        ending_failure = truth_singular_failure(exc, course, simulator.get_context().get_time())
        stop_reason = "failure"
    except OSError as exc:  # the drive log's disk (RunLogWriteError names the path)
        error = f"{type(exc).__name__}: {exc}"
        stop_reason = "error"
    except (RuntimeError, ValueError, ArithmeticError) as exc:
        error = f"{type(exc).__name__}: {exc}"
        stop_reason = "error"
    finally:
        loop_priority.close()
    with _signals("defer", received):
        if bar is not None:
            bar.close()
        diagram.GetSubsystemByName("run_logger").finish()
        run_log.close()
        if run_log.write_error is not None:
            write_errors.append(run_log.write_error)
        context = simulator.get_context()
        playback_html = None
        if meshcat is not None:
            view = diagram.GetSubsystemByName("meshcat_view")
            view.flush(view.GetMyContextFromRoot(context))
            meshcat.StopRecording()
            if panel is not None:
                panel.remove()
            meshcat.PublishRecording()
            playback_html = meshcat.StaticHtml() if writing else None
        log = run_log.to_frame()
        if len(log) == 0:
            raise ValueError(
                f"scenario {scenario.name!r}: nothing was logged ({error or 'stopped'})"
            )
        names = {s.get_name() for s in diagram.GetSystems()}
        if "clustering" in names:  # the PC-VFE pipeline (other friction sources have none)
            clustering = diagram.GetSubsystemByName("clustering")
            clusterer = clustering.clusterer(clustering.GetMyContextFromRoot(context))
            features = log[feature_columns(run_log.feature_dim)].to_numpy()
            log["final_context"] = clusterer.predict(features)
        nmpc = diagram.GetSubsystemByName("nmpc")
        diag = nmpc.GetOutputPort("diagnostics").Eval(nmpc.GetMyContextFromRoot(context))
        station_system = diagram.GetSubsystemByName("station")
        station_status = station_system.GetOutputPort("station_status").Eval(
            station_system.GetMyContextFromRoot(context)
        )
        record = RunRecord(
            scenario=scenario,
            log=log,
            course=course,
            terrain_map=parts.terrain_map,
            estimate_table=_estimate_table(diagram, context) if "fitter" in names else None,
            wall_time_s=wall,
            cpu_time_s=cpu,
            nmpc_updates=int(getattr(diag, "updates", 0)),
            nmpc_fallbacks=int(getattr(diag, "fallback_count", 0)),
            interrupted=interrupted,
            interrupt_signal=received[0] if interrupted and received else None,
            error=error,
            ending_failure=ending_failure,
            stop_reason=stop_reason,
            log_errors=list(run_log.errors),
            write_errors=write_errors,
            station_status=station_status.to_dict(),
            rows_skipped_state_not_finite=diagram.GetSubsystemByName("run_logger").skipped_rows,
        )
        result = write_run_outputs(
            record,
            folder if writing else None,
            playback_html=playback_html,
            reference_xy=course_xy(course),
        )
        result.held_signals = list(received[1:] if interrupted else received)
    # Nothing of the diagram is used any more: free it (a worker runs many in one process).
    release_diagram(diagram)
    return result


def simulate_summary(
    scenario: Scenario | str,
    seed: int | None = None,
    overrides: dict | None = None,
    *,
    out: str | Path | None = None,
) -> dict[str, Any]:
    """Run one whole simulation and return its summary dict (no Meshcat, no progress bar).

    An entry point for scripts and experiment runners (picklable arguments, usable in a worker
    process): ``scenario`` is a :class:`Scenario` or a shipped name / YAML path; ``seed``
    replaces its seed; ``overrides`` replaces dotted fields (``{"estimator": "ukf",
    "fixed.use": "nominal", "laps": 0.5}``, see
    ``pcvfe_drake.runs.friction_sources.apply_overrides``); ``out`` is a run folder to write
    (drive log, summary.json, figures, scenario.yaml), None writes nothing.
    """
    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.runs.friction_sources import apply_overrides

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if seed is not None:
        scenario = dataclasses.replace(scenario, seed=int(seed))
    scenario = apply_overrides(scenario, overrides).validate(f"scenario {scenario.name!r}")
    folder = None
    if out is not None:
        folder = RunFolder(out)
        folder.prepare(overwrite=True)
        folder.write_text(folder.scenario, scenario.to_yaml())
    result = run_simulation(
        scenario, folder, progress=False, write_outputs=out is not None, debug_layers=False
    )
    return result.summary
