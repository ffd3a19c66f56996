"""Vehicle files: every field in its physical range and of the right type, named with the file
and the field, when a command or a scenario loads the vehicle (before any work)."""

from __future__ import annotations

import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.vehicle.params import roboracer


def _car(tmp_path, **changes) -> str:
    import yaml

    data = roboracer().to_dict()
    data.pop("name")
    data.update(changes)
    path = tmp_path / "car.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


CASES = [
    ({"g": 0.0}, "g=0.0 is outside the physical range [1, 30]"),
    ({"g": -9.81}, "g=-9.81 is outside the physical range"),
    ({"m": True}, "m=True must be a number"),
    ({"m": "heavy"}, "m='heavy' must be a number"),
    ({"delta_max": 10.0}, "delta_max=10.0 is outside the physical range [0, 1.6]"),
    ({"h": 100.0}, "h=100.0 is outside the physical range [0, 3]"),
    ({"lf": 50.0}, "lf=50.0 is outside the physical range"),
    ({"mu": 0.0}, "mu=0.0 is outside the physical range"),
    ({"a_max": 1000.0}, "a_max=1000.0 is outside the physical range"),
    ({"v_max": -1.0}, "v_max=-1.0 is outside the physical range"),
    ({"length": 0.3}, "(the wheelbase) must fit within length=0.3 m"),
    ({"delta_dot_min": 1.0}, "delta_dot_min=1.0 is outside the physical range"),
    ({"bogus": 3}, "unknown vehicle parameter"),
    ({"v_max": 0.0}, "v_max=0.0 is outside the physical range [0.1, 100]"),
    ({"name": 5}, "name=5 must be a non-empty string"),
    ({"m": float("nan")}, "m=nan is not finite"),
]


@pytest.mark.parametrize(("changes", "words"), CASES)
def test_a_bad_vehicle_file_is_named_by_fit(tmp_path, capsys, changes, words):
    car = _car(tmp_path, **changes)
    assert main(["fit", str(tmp_path / "never_read.csv"), "--vehicle", car]) == 2
    err = capsys.readouterr().err
    assert f"vehicle file {car}" in err and words in err and "Traceback" not in err


def test_a_bad_vehicle_file_is_named_when_the_scenario_loads(tmp_path, capsys):
    _car(tmp_path, g=0.0)
    scenario = tmp_path / "s.yaml"
    scenario.write_text("vehicle: car.yaml\n")
    out = tmp_path / "run"
    assert main(["simulate", str(scenario), "--no-meshcat", "--out", str(out)]) == 2
    assert "car.yaml: VehicleParams 'car': g=0.0" in capsys.readouterr().err
    assert not out.exists()  # refused before the run folder is made


@pytest.mark.parametrize(
    ("text", "words"),
    [("m: [: :\n", "not valid YAML"), ("- 1\n", "expected a mapping of parameter names")],
)
def test_a_vehicle_file_that_is_not_a_mapping_is_named(tmp_path, capsys, text, words):
    car = tmp_path / "car.yaml"
    car.write_text(text)
    assert main(["fit", str(tmp_path / "x.csv"), "--vehicle", str(car)]) == 2
    err = capsys.readouterr().err
    assert str(car) in err and words in err


def test_every_preset_is_within_the_ranges():
    from pcvfe_drake.vehicle.params import PRESETS, vehicle_problems

    for make in PRESETS.values():
        assert vehicle_problems(make()) == []


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("vehicle: ford_escort\n", "no 'effects' list (write 'effects: []'"),
        ("effects: [{name: drag, fixed: {CdA: 0.1}, std: {CdA: -1.0}}]\n", "must be >= 0"),
        ("effects: []\neffects: [drag]\n", "key 'effects' given twice"),
    ],
)
def test_a_bad_effect_model_file_is_named_when_the_scenario_loads(tmp_path, capsys, text, words):
    (tmp_path / "m.yaml").write_text(text)
    scenario = tmp_path / "s.yaml"
    scenario.write_text("fitter: {model: {file: m.yaml}}\n")
    out = tmp_path / "run"
    assert main(["simulate", str(scenario), "--no-meshcat", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "m.yaml" in err and words in err and "Traceback" not in err
    assert not out.exists()
