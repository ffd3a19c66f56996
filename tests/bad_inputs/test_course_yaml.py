"""Course files as they are checked today: a course that is neither shipped nor a file, a file
that is not YAML or not a course, named with the file (the course's own values: see the course
tests), and a scenario's relative course path taken beside the scenario."""

from __future__ import annotations

from pathlib import Path

import pytest

from pcvfe_drake.control.course import load_course_spec


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("radius_m: [: :\n", "not valid YAML"),
        ("- 1\n- 2\n", "course file"),
        ("no_such_field: 3\n", "course file"),
        ("segments: {kind: straight}\n", "segments must be a list of segments"),
        ("name: a\nname: b\n", "key 'name' given twice"),
    ],
)
def test_a_bad_course_file_is_named(tmp_path, text, words):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=words) as info:
        load_course_spec(path)
    assert str(path) in str(info.value)


def test_an_unknown_course_is_named_with_the_shipped_ones():
    with pytest.raises(ValueError, match="neither a shipped course .*slalom.* nor a file"):
        load_course_spec("no_such_course")


def test_a_scenario_names_a_missing_course_beside_it(tmp_path, capsys):
    from pcvfe_drake.cli import main

    scenario = tmp_path / "s.yaml"
    scenario.write_text("course: courses/gone.yaml\n")
    assert main(["simulate", str(scenario), "--no-meshcat", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert f"{scenario}: field 'course'='courses/gone.yaml' is not a file" in err
    assert str(tmp_path / "courses" / "gone.yaml") in err


@pytest.mark.parametrize(
    ("spacing", "words"),
    [(1.0e-6, "samples of the 890.7 m lap (~178 GB), more than 1000000"), (50.0, "<= 2 m")],
)
def test_a_course_spacing_beyond_its_bounds_is_named(tmp_path, spacing, words):
    import yaml

    from pcvfe_drake.control.course import COURSE_DIR, load_course

    text = Path(__file__).resolve().parents[2] / "pcvfe_drake" / COURSE_DIR / "slalom.yaml"
    data = yaml.safe_load(text.read_text())
    data["spacing_m"] = spacing
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ValueError, match="spacing_m") as info:
        load_course(path)
    assert str(path) in str(info.value) and words in str(info.value)
