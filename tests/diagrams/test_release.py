"""A finished run frees its diagram and what its systems hold (pydrake's cycles through C++
are broken by hand, diagrams/release.py)."""

from __future__ import annotations

import gc

import pytest
from pydrake.systems.framework import Diagram

from pcvfe_drake.diagrams import run_simulation as run_module
from pcvfe_drake.diagrams.scenario_io import load_scenario
from pcvfe_drake.perception.ground_render import GroundRenderer
from pcvfe_drake.runs.runlog import RunLog


def alive() -> tuple[int, int, int]:
    """Simulation diagrams, run logs and ground renderers alive after a full collection."""
    gc.collect()
    objects = gc.get_objects()
    return (
        sum(isinstance(o, Diagram) and o.get_name() == "pcvfe_simulation" for o in objects),
        sum(isinstance(o, RunLog) for o in objects),
        sum(isinstance(o, GroundRenderer) for o in objects),
    )


def short_run():
    scenario = load_scenario("paper_sim").with_run_length(duration_s=0.3)
    run_module.run_simulation(scenario, None, progress=False, write_outputs=False)


def test_a_finished_run_leaves_no_diagram_and_no_data_behind():
    before = alive()
    short_run()
    short_run()
    assert alive() == before


def test_without_the_release_pydrake_keeps_every_run(monkeypatch):
    # Why release_diagram exists: if this fails, pydrake frees finished diagrams by itself and
    # the workaround can go.
    monkeypatch.setattr(run_module, "release_diagram", lambda diagram: 0)
    before = alive()
    short_run()
    leaked = [a - b for a, b in zip(alive(), before, strict=True)]
    if leaked == [0, 0, 0]:
        pytest.fail("pydrake now frees a finished diagram without release_diagram")
    assert leaked == [1, 1, 1]
