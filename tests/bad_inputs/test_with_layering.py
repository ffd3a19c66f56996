"""`--with` layers: each layer's errors name that file, and its paths resolve against it."""

from __future__ import annotations

from pathlib import Path

import pytest

from pcvfe_drake.cli import main

SHIPPED_COURSE = Path(__file__).resolve().parents[2] / "pcvfe_drake/data/courses/slalom.yaml"


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("nmpc: {horizont: 30}\n", "unknown field 'nmpc.horizont'"),
        ("rates: [: :\n", "not valid YAML"),
        ("- a list\n", "must be a mapping of fields"),
        ("clustering: {frame_rate_hz: 5.0}\n", "is set from rates.camera_period_s"),
        ("course: no_such_course.yaml\n", "field 'course'='no_such_course.yaml' is not a file"),
        ("vehicle: no_car.yaml\n", "field 'vehicle'='no_car.yaml' is not a file"),
    ],
)
def test_a_bad_layer_is_named(tmp_path, capsys, text, words):
    layer = tmp_path / "layer.yaml"
    layer.write_text(text)
    out = tmp_path / "run"
    assert main(["simulate", "--with", str(layer), "--no-meshcat", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(layer) in err and words in err and "Traceback" not in err
    assert not out.exists()


def test_a_missing_layer_is_named(tmp_path, capsys):
    missing = tmp_path / "nope.yaml"
    assert (
        main(["simulate", "--with", str(missing), "--no-meshcat", "--out", str(tmp_path / "r")])
        == 2
    )
    assert "nope.yaml" in capsys.readouterr().err


def test_a_layer_path_resolves_against_the_layer_not_the_base(tmp_path):
    from pcvfe_drake.diagrams.scenario_io import load_scenario

    base_dir, layer_dir = tmp_path / "base", tmp_path / "layers"
    base_dir.mkdir()
    layer_dir.mkdir()
    (layer_dir / "c.yaml").write_text(SHIPPED_COURSE.read_text())
    (base_dir / "s.yaml").write_text("name: base\n")
    (layer_dir / "l.yaml").write_text("course: c.yaml\n")
    scenario = load_scenario(base_dir / "s.yaml", layer_dir / "l.yaml")
    assert scenario.course == str((layer_dir / "c.yaml").resolve())
    # A later layer that does not name the course keeps the resolved one.
    (base_dir / "m.yaml").write_text("seed: 3\n")
    again = load_scenario(base_dir / "s.yaml", layer_dir / "l.yaml", base_dir / "m.yaml")
    assert (again.course, again.seed) == (scenario.course, 3)
