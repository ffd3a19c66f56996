"""Running a scenario end to end: simulate in chunks, record Meshcat, write the run folder.

:func:`run_simulation` builds ``MakeSimulation``, advances the simulator in chunks of simulated
time (progress bar with simulated time and real-time factor), stops at the scenario's duration or
lap count, and on any ending (done, Ctrl-C, or an error inside the simulation) closes the drive
log, saves the Meshcat recording as ``playback.html``, and writes ``summary.json`` and the
figures from what was logged.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import (
    ApplySimulatorConfig,
    GetIntegrationSchemes,
    Simulator,
    SimulatorConfig,
)
from pydrake.systems.framework import Diagram

from pcvfe_drake.control.course import Course
from pcvfe_drake.diagrams.debug_layers import LAYERS
from pcvfe_drake.diagrams.meshcat_controls import MeshcatControls
from pcvfe_drake.diagrams.simulation import MakeSimulation, course_xy
from pcvfe_drake.perception.ground_render import render_topdown
from pcvfe_drake.runs.figures import write_figures
from pcvfe_drake.runs.runlog import feature_columns
from pcvfe_drake.runs.scenario import Scenario, excluded_terrains
from pcvfe_drake.runs.summary import summarize_run


class RunFolder:
    """File names of a run folder."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.drive_log = self.root / "drive_log.csv"
        self.summary = self.root / "summary.json"
        self.playback = self.root / "playback.html"
        self.figures = self.root / "figures"
        self.scenario = self.root / "scenario.yaml"


@dataclass
class SimulationResult:
    summary: dict[str, Any]
    figures: dict[str, str | None] = field(default_factory=dict)
    figure_notes: dict[str, str] = field(default_factory=dict)
    playback: Path | None = None
    log_errors: list[str] = field(default_factory=list)
    log: Any = None
    """The run log as a pandas DataFrame (drive-log columns, ``final_context`` included)."""


class LapProgress:
    """Progress along the course [m] from a stream of positions (wrap-around aware)."""

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
    """The fitter's final per-context estimates (id, mu, mu_std, samples) from its
    ``estimate_table`` output (``pcvfe_drake.estimation.context_estimator.EstimateTable``)."""
    fitter = diagram.GetSubsystemByName("fitter")
    table = fitter.GetOutputPort("estimate_table").Eval(fitter.GetMyContextFromRoot(context))
    return [
        {
            "id": int(e.context_id),
            "mu": float(e.theta[0]),
            "mu_std": float(e.theta_std[0]),
            "samples": int(e.samples),
            "status": e.status,
        }
        for e in table.entries
        if int(e.context_id) >= 0
    ]


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
) -> SimulationResult:
    """Simulate ``scenario``; write drive log, playback, summary and figures into ``folder``.

    The run stops at ``scenario.duration_s``, or when ``scenario.laps`` laps are completed (at
    ``scenario.max_duration_s`` at the latest), or at Ctrl-C (``summary["interrupted"]``), or
    when the simulation raises (``summary["error"]``; the outputs are still written).

    With a ``meshcat``: ``debug_layers`` adds the ``/pcvfe/`` debugging layers
    (``MakeSimulation``), and ``controls`` the Meshcat controls (show/hide layers, pause/resume,
    real-time rate; :class:`pcvfe_drake.diagrams.meshcat_controls.MeshcatControls`), polled
    between chunks of ``chunk_s`` simulated seconds.

    ``station``: another station for ``MakeSimulation`` (the LCM station, a replay station);
    ``realtime_rate``: pace simulated time to this many times wall-clock time (the LCM station
    runs at ``scenario.hardware.realtime_rate``; None: the scenario's simulator settings).
    """
    log_path = folder.drive_log if folder is not None and write_outputs else None
    if folder is not None:
        folder.root.mkdir(parents=True, exist_ok=True)
    parts = MakeSimulation(
        scenario, meshcat, log_path=log_path, debug_layers=debug_layers, station=station
    )
    diagram, course, run_log = parts.diagram, parts.course, parts.run_log
    simulator = Simulator(diagram)
    ApplySimulatorConfig(simulator_config(scenario), simulator)
    if realtime_rate is not None:
        simulator.set_target_realtime_rate(realtime_rate)
    if meshcat is not None:
        meshcat.StartRecording(frames_per_second=1.0 / scenario.rates.view_period_s)
    panel = None
    if meshcat is not None and controls:
        panel = MeshcatControls(
            meshcat, LAYERS if debug_layers else (), realtime_rate=realtime_rate or 0.0
        )
    stop_t = scenario.stop_time_s()
    laps_goal = scenario.laps if scenario.duration_s is None else None
    lap_progress = LapProgress(course)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(
            total=stop_t,
            unit="s sim",
            bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}{postfix}]",
        )
    interrupted = False
    error = None
    rows_seen = 0
    wall = 0.0
    cpu = 0.0
    try:
        simulator.Initialize()
        # Pace from here: the LCM station's initialization may have waited for the vehicle's
        # first message, and catching up on that wait would run ahead of the messages.
        simulator.ResetStatistics()
        t = 0.0
        while t < stop_t - 1e-9:
            if panel is not None:
                panel.poll(simulator)
            target = min(t + chunk_s, stop_t)
            w0, c0 = time.perf_counter(), time.process_time()
            simulator.AdvanceTo(target)
            wall += time.perf_counter() - w0
            cpu += time.process_time() - c0
            t = simulator.get_context().get_time()
            rows = run_log.rows_since(rows_seen)
            rows_seen += len(rows)
            laps = lap_progress.update(np.array([[r[1], r[2]] for r in rows]).reshape(-1, 2))
            if bar is not None:
                bar.update(target - bar.n)
                ctx = int(rows[-1][run_log.columns.index("context")]) if rows else -1
                bar.set_postfix_str(
                    f"t={t:.0f}s rtf={t / max(wall, 1e-9):.1f}x laps={laps:.2f} ctx={ctx}"
                )
            if laps_goal is not None and laps >= laps_goal:
                break
    except KeyboardInterrupt:
        interrupted = True
    except (RuntimeError, ValueError, ArithmeticError) as exc:
        error = f"{type(exc).__name__}: {exc}"
    finally:
        if bar is not None:
            bar.close()
        diagram.GetSubsystemByName("run_logger").finish()
        run_log.close()
    context = simulator.get_context()
    result = SimulationResult(summary={}, log_errors=list(run_log.errors))
    if meshcat is not None:
        view = diagram.GetSubsystemByName("meshcat_view")
        view.flush(view.GetMyContextFromRoot(context))
        meshcat.StopRecording()
        if panel is not None:
            panel.remove()
        meshcat.PublishRecording()
        if folder is not None and write_outputs:
            folder.playback.write_text(meshcat.StaticHtml())
            result.playback = folder.playback
    log = run_log.to_frame()
    if len(log) == 0:
        raise ValueError(f"scenario {scenario.name!r}: nothing was logged ({error or 'stopped'})")
    terrain_map = parts.terrain_map
    clustering = diagram.GetSubsystemByName("clustering")
    clusterer = clustering.clusterer(clustering.GetMyContextFromRoot(context))
    log["final_context"] = clusterer.predict(log[feature_columns(run_log.feature_dim)].to_numpy())
    table = _estimate_table(diagram, context)
    summary = summarize_run(
        log,
        scenario=scenario.name,
        wall_time_s=wall,
        terrain_mu={t.name: t.mu for t in terrain_map.terrains},
        excluded_terrains=excluded_terrains(scenario),
        course=course,
        estimate_table=table,
        interrupted=interrupted,
    )
    summary["cpu_time_s"] = cpu
    summary["realtime_factor_cpu"] = summary["sim_time_s"] / cpu if cpu > 0 else None
    summary["truth_model"] = scenario.truth_model
    summary["feature_backend"] = scenario.features.backend
    summary["seed"] = scenario.seed
    if error is not None:
        summary["error"] = error
    station_system = diagram.GetSubsystemByName("station")
    status = station_system.GetOutputPort("station_status").Eval(
        station_system.GetMyContextFromRoot(context)
    )
    summary["station_status"] = status.to_dict()
    summary["rows_skipped_state_not_finite"] = diagram.GetSubsystemByName("run_logger").skipped_rows
    nmpc = diagram.GetSubsystemByName("nmpc")
    diag = nmpc.GetOutputPort("diagnostics").Eval(nmpc.GetMyContextFromRoot(context))
    summary["nmpc_fallbacks"] = int(getattr(diag, "fallback_count", 0))
    summary["nmpc_updates"] = int(getattr(diag, "updates", 0))
    result.summary = summary
    result.log = log
    if folder is not None and write_outputs:
        x0, x1, y0, y1 = terrain_map.bounds_m
        map_image = render_topdown(terrain_map, px_per_m=2.0)
        result.figures = write_figures(
            log,
            folder.figures,
            summary,
            map_image=map_image,
            map_bounds_m=(x0, x1, y0, y1),
            reference_xy=course_xy(course),
            log_dir=folder.root,
        )
        if result.figures.get("fig7_reidentification") is None:
            result.figure_notes["fig7_reidentification"] = "no re-identification in this run"
        summary["files"] = {
            "drive_log": folder.drive_log.name,
            "playback": folder.playback.name if result.playback else None,
            "figures": {
                k: (Path(v).relative_to(folder.root).as_posix() if v else None)
                for k, v in result.figures.items()
            },
        }
        folder.summary.write_text(json.dumps(summary, indent=2, allow_nan=False))
    return result
