"""Scenario dataclasses, shipped scenario files and the YAML loader's error messages."""

from __future__ import annotations

import pytest

from pcvfe_drake.contexts.clustering import ClusteringParams
from pcvfe_drake.control.nmpc import NmpcConfig
from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.ukf import UkfConfig
from pcvfe_drake.perception.camera import CameraConfig
from pcvfe_drake.runs.scenario import (
    DEFAULT_SCENARIO,
    Scenario,
    resolve_scenario_path,
    shipped_scenarios,
)


def test_shipped_scenarios_load_with_their_values():
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    assert {"paper_sim", "paper_sim_mb", "roboracer"} <= set(shipped_scenarios())
    default = load_scenario(None)
    assert default.name == DEFAULT_SCENARIO == "paper_sim"
    assert (default.vehicle, default.world, default.truth_model) == ("ford_escort", "paper", "st")
    assert default.laps == 1.0 and default.duration_s is None
    assert default.features.backend == "descriptor" and not default.uses_clip
    mb = load_scenario("paper_sim_mb")
    assert mb.truth_model == "mb"
    rr = load_scenario("roboracer")
    assert (rr.vehicle, rr.world, rr.course) == ("roboracer", "paper_small", "")
    assert rr.camera.height_m == 0.5
    from pcvfe_drake.diagrams.world_io import scenario_course

    assert scenario_course(rr).name == "slalom_small"
    assert scenario_course(default).name == "slalom"
    for s in (default, mb, rr):
        # One log row per NMPC update (the logged input is held over each row); the clustering
        # assigns each camera frame 1 ms after it is taken, in the same camera period.
        assert s.rates.log_period_s <= s.rates.nmpc_period_s
        assert 0 < s.rates.clustering_frame_offset_s < s.rates.camera_period_s


def test_yaml_overrides_nested_fields_and_keeps_defaults(tmp_path):
    from pcvfe_drake.diagrams.scenario_io import load_scenario, save_scenario

    path = tmp_path / "mine.yaml"
    path.write_text(
        "name: mine\nduration_s: 12.5\nrates: {camera_period_s: 0.05}\n"
        "clustering: {min_cluster_duration_s: 3.0, max_stored: 1500}\n"
        "nmpc: {horizon: 30, model: ks}\n"
    )
    s = load_scenario(path)
    assert s.name == "mine" and s.duration_s == 12.5 and s.stop_time_s() == 12.5
    assert (
        s.rates.camera_period_s == 0.05 and s.rates.nmpc_period_s == Scenario().rates.nmpc_period_s
    )
    assert (s.clustering.min_cluster_duration_s, s.clustering.max_stored) == (3.0, 1500)
    assert s.clustering.gate_scale == ClusteringParams().gate_scale
    assert s.clustering_params().frame_rate_hz == 20.0
    assert (s.nmpc.horizon, s.nmpc.model, s.nmpc_config().dt_s) == (30, "ks", 0.05)
    assert s.camera == Scenario().camera  # the scenario's camera default (effects on)
    again = load_scenario(save_scenario(s, tmp_path / "again.yaml"))
    assert again == s


def test_the_scenario_embeds_the_core_configs():
    """One source of truth: the scenario's blocks are the core's config classes themselves."""
    s = Scenario()
    assert type(s.camera) is CameraConfig and type(s.clustering) is ClusteringParams
    assert type(s.fitter) is LiveFitConfig and type(s.nmpc) is NmpcConfig
    assert s.fitter == LiveFitConfig() and s.nmpc == NmpcConfig()
    assert s.clustering == ClusteringParams()
    assert type(s.ukf) is UkfConfig and s.ukf == UkfConfig()
    assert s.camera == CameraConfig(exposure_s=0.002, exposure_jitter=0.05, noise_std=3.0)


def test_layers_apply_in_order(tmp_path):
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    (tmp_path / "a.yaml").write_text("seed: 3\nnmpc: {model: ks}\ncamera: {noise_std: 0.0}\n")
    (tmp_path / "b.yaml").write_text("seed: 4\n")
    s = load_scenario("roboracer", tmp_path / "a.yaml", tmp_path / "b.yaml")
    rr = load_scenario("roboracer")
    assert (s.name, s.vehicle, s.laps, s.camera.height_m) == ("roboracer", "roboracer", 2.0, 0.5)
    assert s.rates.recluster_period_s == rr.rates.recluster_period_s == 5.0
    assert (s.seed, s.nmpc.model, s.camera.noise_std) == (4, "ks", 0.0)
    assert s.camera.exposure_s == rr.camera.exposure_s == 0.002


@pytest.mark.parametrize(
    ("text", "check"),
    [
        ("duration_s: 2e-3", lambda s: s.duration_s == 0.002),
        ("duration_s: 1e1", lambda s: s.duration_s == 10.0),
        ("max_duration_s: 1.0e3", lambda s: s.max_duration_s == 1.0e3),
        ("rates: {camera_period_s: 5E-2}", lambda s: s.rates.camera_period_s == 0.05),
        ("seed: 1e1", lambda s: s.seed == 10),
        ("clustering: {max_stored: 2.0e3}", lambda s: s.clustering.max_stored == 2000),
        ("", lambda s: s == Scenario()),
        ("# only a comment\n", lambda s: s == Scenario()),
    ],
)
def test_yaml_12_numbers_and_empty_files(tmp_path, text, check):
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    path = tmp_path / "n.yaml"
    path.write_text(text)
    assert check(load_scenario(path))


def test_a_binary_file_is_named(tmp_path):
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    path = tmp_path / "image.yaml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00binary")
    with pytest.raises(ValueError, match=r"image\.yaml: not a scenario file \(not UTF-8"):
        load_scenario(path)


def test_simulator_settings_mirror_drakes_simulator_config():
    import dataclasses

    from pydrake.systems.analysis import SimulatorConfig

    from pcvfe_drake.runs.scenario import SimulatorSettings

    drake = {f.name: f.type for f in SimulatorConfig.__fields__ if f.name != "start_time"}
    ours = {f.name: f.type for f in dataclasses.fields(SimulatorSettings)}
    assert ours == drake


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("clustering: {min_cluster_size: 3}", "unknown field 'clustering.min_cluster_size'"),
        ("rates: {camera_period_s: fast}", "'rates.camera_period_s' must be a number"),
        ("seed: 1.5", "'seed' must be an integer"),
        ("rates: 3", "field 'rates' must be a mapping"),
        ("truth_model: rigid", "truth_model='rigid'"),
        ("rates: {nmpc_period_s: -0.05}", "rates.nmpc_period_s=-0.05"),
        ("laps: null", "laps and duration_s are both unset"),
        ("nmpc: {model: pid}", "nmpc: NmpcConfig.model='pid'"),
        ("rates: {clustering_frame_offset_s: 0.1}", "rates.clustering_frame_offset_s=0.1"),
        ("rates: {clustering_frame_offset_s: -0.001}", "rates.clustering_frame_offset_s=-0.001"),
        ("features: {clip_threads: 0}", "features.clip_threads=0"),
        ("seed: 1.5e0", "'seed' must be an integer"),
        ("nmpc: {dt_s: 0.1}", "'nmpc.dt_s' is set from rates.nmpc_period_s"),
        ("clustering: {seed: 3}", "'clustering.seed' is set from seed"),
        ("fitter: {sample_period_s: 0.02}", "'fitter.sample_period_s' is set from rates"),
        ("nmpc: {horizon: 1}", "NmpcConfig.horizon=1 must be >= 2"),
        ("camera: {fov_deg: 200}", "CameraConfig.fov_deg = 200.0 is out of range"),
        ("fitter: {prior_theta: [1.0, -2.0, 3.0]}", "LiveFitConfig.prior_theta must be 3"),
        ("simulator: {max_step_size: 0}", "simulator.max_step_size=0.0"),
        ("ukf: {mu_walk_std: 0}", "ukf: UkfConfig.mu_walk_std=0.0 must be > 0"),
        ("ukf: {process_std: [0.1, 0.1]}", "UkfConfig.process_std must be 7 numbers > 0"),
        ("ukf: {mu_bounds: [1.0, 0.5]}", "UkfConfig.mu_bounds=[1.0, 0.5] must be [lo, hi]"),
        ("ukf: {mu0: 3.0}", "UkfConfig.mu0=3.0 must be None or within mu_bounds"),
        ("ukf: {alpha: 0}", "UkfConfig.alpha=0.0 must be in (0, 1]"),
        ("ukf: {period_s: 0.02}", "'ukf.period_s' is set from rates.fitter_sample_period_s"),
        ("ukf: {mu_walk: 0.1}", "unknown field 'ukf.mu_walk'"),
        ("name: [1, 2", "not valid YAML"),
        ("- 1\n- 2", "the document must be a mapping"),
    ],
)
def test_malformed_scenarios_name_file_and_field(tmp_path, text, message):
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match="bad.yaml") as info:
        load_scenario(path)
    assert message in str(info.value)


def test_unknown_names_are_clear_errors(tmp_path):
    from pcvfe_drake.diagrams.scenario_io import load_scenario
    from pcvfe_drake.diagrams.world_io import scenario_world

    with pytest.raises(FileNotFoundError, match="neither a file nor a shipped scenario"):
        resolve_scenario_path("no_such_scenario")
    path = tmp_path / "v.yaml"
    path.write_text("vehicle: my_car.yaml\n")
    with pytest.raises(FileNotFoundError, match="field 'vehicle'"):
        load_scenario(path)
    with pytest.raises(FileNotFoundError, match="world 'moon' is neither a file nor a shipped"):
        scenario_world(Scenario(world="moon"))
    path.write_text("terrain_layout: paper\n")
    with pytest.raises(ValueError, match="field 'terrain_layout' was replaced by 'world'"):
        load_scenario(path)


def test_run_length_overrides():
    s = Scenario()
    assert s.with_run_length(duration_s=5).stop_time_s() == 5.0
    by_laps = s.with_run_length(laps=2)
    assert by_laps.laps == 2.0 and by_laps.duration_s is None
    assert by_laps.stop_time_s() == s.max_duration_s
    with pytest.raises(ValueError, match="either"):
        s.with_run_length(laps=1, duration_s=3)
