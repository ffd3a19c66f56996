"""Scenario files: sizes bounded before a run starts (with what they would cost), run-folder
names that cannot leave runs/, and paths resolved against the file that names them."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.runs import run_folder
from pcvfe_drake.runs.run_folder import DEFAULT_RUNS_DIR, run_folder_name

SHIPPED_COURSE = Path(__file__).resolve().parents[2] / "pcvfe_drake/data/courses/slalom.yaml"


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("rates: {log_period_s: 1.0e-6}", "rates.log_period_s=1e-06: at least 0.001 s"),
        ("rates: {log_period_s: 1.0e-6}", "the drive log would have 9e+08 rows (~630 GB)"),
        ("rates: {fitter_sample_period_s: 1.0e-5}", "1e+05 events per simulated second"),
        ("rates: {camera_period_s: 1.0e-4}", "rates.camera_period_s=0.0001: at least"),
        ("max_duration_s: 1.0e9", "max_duration_s=1000000000.0: the drive log would have"),
        ("simulator: {max_step_size: 1.0e-7}", "1e+07 steps per simulated second"),
        ("nmpc: {horizon: 100000}", "horizon=100000 must be <= 400 steps"),
        ("nmpc: {horizon: 100000}", "900000 variables"),
        ("nmpc: {max_speed_mps: -3.0}", "max_speed_mps=-3.0 must be >= 0 m/s"),
    ],
)
def test_sizes_beyond_their_bounds_are_refused_before_the_run(tmp_path, capsys, text, words):
    layer = tmp_path / "layer.yaml"
    layer.write_text(text + "\n")
    out = tmp_path / "run"
    assert main(["simulate", "--with", str(layer), "--no-meshcat", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(layer) in err and words in err and "Traceback" not in err
    assert not out.exists()


def test_a_command_line_duration_is_bounded_too(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", "--duration", "1e9", "--no-meshcat", "--out", str(out)]) == 2
    assert "duration_s=1000000000.0: the drive log would have 2e+10 rows" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    "name", ["/etc/evil", "../../escape", "a\nb", "..", "x/../../y", "C:\\temp\\x", " "]
)
def test_a_run_folder_name_is_one_component_under_runs(name):
    folder = run_folder_name(name, datetime(2026, 1, 2, 3, 4, 5))
    path = DEFAULT_RUNS_DIR / folder
    assert path.parent == DEFAULT_RUNS_DIR and len(path.parts) == 2
    assert folder.endswith("-20260102-030405") and "\n" not in folder
    assert not folder.startswith(".")


def test_simulate_puts_an_odd_scenario_name_under_runs(tmp_path, monkeypatch, capsys):
    scenario = tmp_path / "s.yaml"
    scenario.write_text('name: "../../../tmp/evil\\nline"\n')
    seen = []

    def stop(self, overwrite=False):
        seen.append(self.root)
        raise run_folder.RunFolderError("stopped here by the test")

    monkeypatch.setattr(run_folder.RunFolder, "prepare", stop)
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", str(scenario), "--no-meshcat"]) == 2
    (root,) = seen
    assert root.parent == DEFAULT_RUNS_DIR and root.name.startswith("tmp_evil_line-")


def test_paths_resolve_against_the_scenario_file_and_the_saved_copy_runs_anywhere(
    tmp_path, monkeypatch
):
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    here = tmp_path / "project" / "scenarios"
    here.mkdir(parents=True)
    (here / "my_course.yaml").write_text(SHIPPED_COURSE.read_text())
    (here / "car.yaml").write_text("name: car\n" + _roboracer_fields())
    # the paper's fitter: a vehicle file without a calibrated model beside it
    (here / "s.yaml").write_text(
        "course: my_course.yaml\nvehicle: car.yaml\nestimator: pcvfe_paper\n"
    )
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    scenario = load_scenario(here / "s.yaml")
    assert scenario.course == str((here / "my_course.yaml").resolve())
    assert scenario.vehicle == str((here / "car.yaml").resolve())
    # The run folder's scenario.yaml stores the absolute paths: it loads from anywhere.
    run = tmp_path / "run"
    run.mkdir()
    (run / "scenario.yaml").write_text(scenario.to_yaml())
    monkeypatch.chdir(tmp_path)
    again = load_scenario(run / "scenario.yaml")
    assert (again.course, again.vehicle) == (scenario.course, scenario.vehicle)


def test_a_relative_course_is_not_taken_from_the_working_directory(tmp_path, monkeypatch):
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    (tmp_path / "my_course.yaml").write_text(SHIPPED_COURSE.read_text())
    sub = tmp_path / "scenarios"
    sub.mkdir()
    (sub / "s.yaml").write_text("course: my_course.yaml\n")
    monkeypatch.chdir(tmp_path)  # the course is here, not beside the scenario
    with pytest.raises(FileNotFoundError, match="field 'course'='my_course.yaml' is not a file"):
        load_scenario(sub / "s.yaml")


def _roboracer_fields() -> str:
    from pcvfe_drake.vehicle.params import roboracer

    data = roboracer().to_dict()
    data.pop("name")
    return "".join(f"{k}: {v}\n" for k, v in data.items() if v is not None)
