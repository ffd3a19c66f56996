"""Course files as they are checked today: a course that is neither shipped nor a file, a file
that is not YAML or not a course, named with the file (the course's own values: see the course
tests), and a scenario's relative course path taken beside the scenario."""

from __future__ import annotations

import pytest

from pcvfe_drake.control.course import load_course_spec


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("radius_m: [: :\n", "not valid YAML"),
        ("- 1\n- 2\n", "course file"),
        ("no_such_field: 3\n", "course file"),
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
