"""What a scenario names beyond its own values (its world, the terrains it changes there, its
integration scheme, its CLIP folder, an initial speed within the car's top speed), checked when
the scenario loads and named with the file that set the field; a key given twice in any config
file; sizes whose cost is not bounded by the run length (the clustering store, the controller
period, the fitter's buffer and windows)."""

from __future__ import annotations

import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.contexts.clustering_params import MAX_STORED, ClusteringParams
from pcvfe_drake.control.course import load_course_spec
from pcvfe_drake.vehicle.params import load_vehicle


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("world: moon\n", "world: world 'moon' is neither a file nor a shipped world"),
        ("vehicle: ''\n", "vehicle='': must name a preset or a YAML file"),
        ("terrains: {lava: {mu: 0.5}}\n", "terrains.lava: the world 'paper' has no terrain"),
        ("simulator: {integration_scheme: euler_magic}\n", "integration_scheme='euler_magic'"),
        ("features: {backend: no_clip_here}\n", "features.backend='no_clip_here': not a CLIP"),
        ("initial_speed_mps: 1000\n", "initial_speed_mps=1000.0 is above the top speed"),
        ("rates: {nmpc_period_s: 10.0}\n", "rates.nmpc_period_s=10.0: at most 0.5 s"),
        ("clustering: {max_stored: 1000000000}\n", f"must be <= {MAX_STORED} frames"),
        ("seed: 1\nname: a\nseed: 2\n", "key 'seed' given twice in one mapping"),
        ("fitter: {buffer_s: 1.0e9}\n", "it keeps 1e+11 samples per context (~7.2e+03 GB each)"),
        ("fitter: {horizon_steps: 1000000}\n", "no window would ever be fitted"),
        ("fitter: {max_windows: 1000000000}\n", "at most 20000 windows per refit"),
    ],
)
def test_the_scenario_file_that_set_the_field_is_named(tmp_path, capsys, text, words):
    base = tmp_path / "base.yaml"
    base.write_text("seed: 1\n")
    layer = tmp_path / "layer.yaml"
    layer.write_text(text)
    out = tmp_path / "run"
    args = ["simulate", str(base), "--with", str(layer), "--no-meshcat", "--out", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if ": error: " in x)
    assert str(layer) in line and str(base) not in line
    assert words in err and "Traceback" not in err
    assert not out.exists()


def test_a_key_given_twice_in_a_vehicle_or_course_file_is_refused(tmp_path):
    car = tmp_path / "car.yaml"
    car.write_text("m: 3.5\nm: 35.0\n")
    with pytest.raises(ValueError, match=r"car.yaml: not valid YAML.*key 'm' given twice"):
        load_vehicle(car)
    course = tmp_path / "c.yaml"
    course.write_text("name: c\nspacing_m: 0.1\nspacing_m: 1.0\n")
    with pytest.raises(ValueError, match=r"c.yaml: not valid YAML.*'spacing_m' given twice"):
        load_course_spec(course)


def test_the_clustering_store_is_bounded_and_says_its_cost():
    with pytest.raises(ValueError, match=r"max_stored=100000 must be <= 10000 .* ~80 GB"):
        ClusteringParams(max_stored=100_000)
    assert ClusteringParams(max_stored=MAX_STORED).max_stored == MAX_STORED
