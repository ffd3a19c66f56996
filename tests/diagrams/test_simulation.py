"""Whole-diagram tests: one short closed-loop run of the shortened default scenario."""

from __future__ import annotations

import dataclasses
import json

import pytest
from pydrake.geometry import Meshcat, MeshcatParams

from pcvfe_drake.contexts.clustering import ClusteringParams
from pcvfe_drake.diagrams import run_simulation as run_module
from pcvfe_drake.diagrams.run_simulation import RunFolder, run_simulation
from pcvfe_drake.diagrams.scenario_io import load_scenario
from pcvfe_drake.diagrams.simulation import MakeSimulation
from pcvfe_drake.diagrams.station import (
    SIM_ONLY_OUTPUTS,
    STATION_INPUTS,
    STATION_OUTPUTS,
    MakeVehicleStation,
)
from pcvfe_drake.runs.drivelog import read_drive_log


def short_scenario(duration_s: float):
    """The default scenario, shortened: contexts form after 2 s of frames, re-clustering every
    5 s, and a start 80 m into the southern S-curve side (44 m west of the gravel strip), so the
    start terrain (sand, ~10 s) and the next one (concrete) both get contexts and fits within
    20 s of driving."""
    s = load_scenario("paper_sim").with_run_length(duration_s=duration_s)
    return dataclasses.replace(
        s,
        start_s_m=80.0,
        rates=dataclasses.replace(s.rates, recluster_period_s=5.0),
        clustering=ClusteringParams(min_cluster_duration_s=2.0, min_samples_duration_s=1.0),
    )


def test_station_exports_the_fixed_port_names():
    scenario = short_scenario(1.0)
    station = MakeVehicleStation(scenario)
    assert station.get_name() == "vehicle_station"
    inputs = {station.get_input_port(i).get_name() for i in range(station.num_input_ports())}
    outputs = {station.get_output_port(i).get_name() for i in range(station.num_output_ports())}
    assert inputs == set(STATION_INPUTS) == {"actuation"}
    assert outputs == set(STATION_OUTPUTS) | set(SIM_ONLY_OUTPUTS)


def test_closed_loop_discovers_contexts_fits_friction_and_tracks(tmp_path):
    scenario = short_scenario(20.0)
    params = MeshcatParams()
    params.host = "localhost"
    meshcat = Meshcat(params)
    folder = RunFolder(tmp_path / "run")
    result = run_simulation(scenario, folder, meshcat=meshcat, progress=False)
    s = result.summary

    # Tracks the course without failures.
    assert s["catastrophic_failures"] == 0
    assert s["lateral_error_rms_m"] < 0.3
    assert 3.0 < s["mean_speed_mps"] < 8.0
    assert 0.08 < s["laps_fraction"] < 0.15  # ~95 m of the 891 m lap
    # Sand (start) and concrete discovered as distinct contexts, each fitted near its true mu.
    by_terrain = {e["majority_terrain"]: e for e in s["mu_estimates"] if e["majority_share"] > 0.8}
    assert {"sand", "concrete"} <= set(by_terrain)
    assert by_terrain["sand"]["id"] != by_terrain["concrete"]["id"]
    for name in ("sand", "concrete"):
        e = by_terrain[name]
        assert e["fit_status"] == "fitted", e
        assert abs(e["mu_hat"] - e["true_mu"]) < 0.05, e
        assert e["std"] is not None
    # Concrete, the current terrain, holds its samples. (Sand's were relabelled: in this short
    # scenario a re-clustering at 15 s merges sand's clusters under a fresh id, and the fitter's
    # samples follow the clustering's labels, paper eq. 5d; tests/estimation/test_relabel.py
    # covers that.)
    assert by_terrain["concrete"]["samples"] > 100
    # Noise mostly while a new terrain waits for its first re-clustering (here 0.62: in 20 s the
    # contexts are young and small, and a small context's gate is set below its two strays,
    # density_gate._scaled_quantile; 0.54 while they set it).
    assert s["noise_fraction"] < 0.66

    # Run folder: drive log on disk (incremental writer), summary, playback, figures.
    log = read_drive_log(folder.drive_log)
    assert len(log) == s["log_rows"] and {"context", "mu_hat", "f_00", "image"} <= set(log)
    assert json.loads(folder.summary.read_text())["scenario"] == "paper_sim"
    # The scene (ground texture, path, car, trail, animation) is embedded in the page.
    html = folder.playback.read_text()
    empty = Meshcat(params).StaticHtml()
    assert html.startswith("<!DOCTYPE html>") and len(html) > len(empty) + 300_000
    assert result.figures["fig4_contexts_map"] and result.figures["fig5_mu_over_time"]
    assert (folder.root / "frames").is_dir()
    # The debugging layers were drawn: the plan, the friction circle with the true circle (the
    # simulated station has truth), camera frames, and a feature cloud per re-clustering.
    for path in (
        "plan/trajectory/00/00000",
        "plan/reference/00",
        "friction_circle/mu_hat/line",
        "friction_circle/mu_true/line",
        "friction_circle/actual",
        "camera/frame/00000",
        "features/clouds/00001/points",
    ):
        assert meshcat.HasPath(f"/pcvfe/{path}"), path
    # The controls were removed at the end, so the playback has none.
    assert not meshcat.GetSliderNames() and not meshcat.GetButtonNames()


def test_every_system_is_named_and_connected():
    parts = MakeSimulation(short_scenario(1.0))
    diagram = parts.diagram
    assert diagram.get_name() == "pcvfe_simulation"
    root = diagram.CreateDefaultContext()
    for name in ("station", "features", "clustering", "fitter", "nmpc", "run_logger"):
        system = diagram.GetSubsystemByName(name)
        context = system.GetMyContextFromRoot(root)
        for i in range(system.num_input_ports()):
            assert system.get_input_port(i).HasValue(context), (name, i)
    # The fitter relabels its samples with the clustering's stored frames (paper eq. 5d).
    fitter, clustering = (diagram.GetSubsystemByName(n) for n in ("fitter", "clustering"))
    frames = fitter.GetInputPort("frame_labels").Eval(fitter.GetMyContextFromRoot(root))
    assert frames.version == 0 and frames.frame_period_s == clustering.frame_period_s
    assert fitter.config.relabel
    # No vector log sinks: the drive log is the run's one record (the summary reads it).
    names = {diagram.GetSystems()[i].get_name() for i in range(len(diagram.GetSystems()))}
    assert not any(n.startswith("log_") for n in names), names


def test_debug_layers_are_named_and_connected():
    params = MeshcatParams()
    params.host = "localhost"
    diagram = MakeSimulation(short_scenario(1.0), Meshcat(params)).diagram
    root = diagram.CreateDefaultContext()
    views = ("meshcat_view", "plan_view", "friction_circle_view", "camera_view", "feature_view")
    for name in views:
        system = diagram.GetSubsystemByName(name)
        context = system.GetMyContextFromRoot(root)
        for i in range(system.num_input_ports()):
            assert system.get_input_port(i).HasValue(context), (name, i)
    without = MakeSimulation(short_scenario(1.0), Meshcat(params), debug_layers=False).diagram
    assert not without.HasSubsystemNamed("plan_view")
    circle = diagram.GetSubsystemByName("friction_circle_view")
    assert circle.HasInputPort("true_mu")  # the simulated station has truth


def test_debug_layers_on_a_station_without_truth():
    from pcvfe_drake.diagrams.station import MakeVehicleStation
    from pcvfe_drake.hardware.settings import LcmBusSettings

    scenario = short_scenario(1.0)
    scenario.hardware.lcm_buses = {"default": LcmBusSettings(lcm_url="memq://")}
    station = MakeVehicleStation(scenario, hardware=True)
    assert not station.HasOutputPort("true_mu")
    params = MeshcatParams()
    params.host = "localhost"
    diagram = MakeSimulation(scenario, Meshcat(params), station=station).diagram
    circle = diagram.GetSubsystemByName("friction_circle_view")
    assert not circle.HasInputPort("true_mu")  # no true circle without truth
    root = diagram.CreateDefaultContext()
    for name in ("plan_view", "friction_circle_view", "camera_view", "feature_view"):
        system = diagram.GetSubsystemByName(name)
        context = system.GetMyContextFromRoot(root)
        for i in range(system.num_input_ports()):
            assert system.get_input_port(i).HasValue(context), (name, i)


@pytest.mark.parametrize("stop", [KeyboardInterrupt, RuntimeError])
def test_ctrl_c_or_an_error_keeps_what_was_logged(tmp_path, monkeypatch, stop):
    class StoppedSimulator(run_module.Simulator):
        def AdvanceTo(self, t):
            if t > 2.0:
                raise stop("stopped by the test")
            return super().AdvanceTo(t)

    monkeypatch.setattr(run_module, "Simulator", StoppedSimulator)
    folder = RunFolder(tmp_path / "run")
    scenario = short_scenario(10.0)
    result = run_simulation(scenario, folder, progress=False)
    s = result.summary
    assert s["interrupted"] is (stop is KeyboardInterrupt)
    assert ("stopped by the test" in s.get("error", "")) is (stop is RuntimeError)
    period = scenario.rates.log_period_s
    assert period == pytest.approx(0.05)  # the NMPC's rate: one row per held input
    assert s["sim_time_s"] == pytest.approx(2.0 + period, abs=1e-6)
    rows = int(round(2.0 / period)) + 1  # rows at t = 0, period, ..., 2.0 s
    assert len(read_drive_log(folder.drive_log)) == s["log_rows"] == rows
    assert json.loads(folder.summary.read_text())["log_rows"] == rows
    assert result.figures["fig5_mu_over_time"]


def test_the_scenario_configs_reach_the_systems():
    """The diagram is built from the scenario's own configs, with the rates filled in."""
    from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
    from pcvfe_drake.handing.config import HandingConfig

    handing = HandingConfig(noise_hold_s=0.5)
    s = dataclasses.replace(
        short_scenario(1.0),
        fitter=LiveFitConfig(horizon_steps=8, stride_steps=4, min_windows=10, handing=handing),
    )
    s.nmpc.horizon = 30
    s.rates.nmpc_period_s = 0.04
    parts = MakeSimulation(s)
    fitter = parts.diagram.GetSubsystemByName("fitter")
    # the data rate from rates, the handing's planner share from nmpc.speed_margin
    assert fitter._config == dataclasses.replace(s.fitter, sample_period_s=0.01)
    assert fitter.planner_mu_share == s.nmpc.speed_margin**2
    nmpc = parts.diagram.GetSubsystemByName("nmpc")
    assert (nmpc.controller.config.horizon, nmpc.controller.config.dt_s) == (30, 0.04)
