"""Each friction source drives the closed loop from a scenario (short runs, ST truth)."""

import numpy as np
import pandas as pd
import pytest

from pcvfe_drake.diagrams.run_simulation import simulate_summary
from pcvfe_drake.diagrams.scenario_io import load_scenario
from pcvfe_drake.diagrams.simulation import MakeSimulation
from pcvfe_drake.runs.friction_sources import apply_overrides

SHORT = {"truth_model": "st", "simulator.integration_scheme": "runge_kutta2", "duration_s": 2.0}


@pytest.mark.parametrize("estimator", ["oracle", "fixed", "lookup", "ukf", "kmpc"])
def test_every_source_runs_and_feeds_what_it_should(estimator, tmp_path):
    s = simulate_summary("paper_eval", 0, {**SHORT, "estimator": estimator}, out=tmp_path)
    assert s["estimator"] == estimator and s["scored_on_truth"] and s["sensing"] == "ins"
    assert s["catastrophic_failures"] == 0 and s["sim_time_s"] > 1.9
    log = pd.read_csv(tmp_path / "drive_log.csv")
    mu_hat, mu_true = log["mu_hat"].to_numpy(), log["mu_true"].to_numpy()
    # measured state != true state (sensing on), by about the configured noise
    dx = (log["sx"] - log["true_sx"]).to_numpy()
    assert 0.005 < np.std(dx) < 0.05
    if estimator == "oracle":
        np.testing.assert_allclose(mu_hat[1:], mu_true[1:])
    elif estimator == "fixed":
        assert np.all(mu_hat == 0.3)  # the conservative value
    elif estimator == "kmpc":
        assert np.all(mu_hat == pytest.approx(1.0489))  # nominal, for the speed profile
    elif estimator == "lookup":
        assert np.all(mu_hat[5:] == 0.45)  # sand, from the table
        assert set(log["context"][5:]) == {2}  # sand's class index in the table
    elif estimator == "ukf":
        assert np.all(np.isfinite(mu_hat)) and mu_hat[-1] != mu_hat[0]


def test_the_ukf_tuning_comes_from_the_scenario():
    overrides = {**SHORT, "estimator": "ukf", "ukf.mu_walk_std": 0.1, "ukf.mu0": 0.6}
    scenario = apply_overrides(load_scenario("paper_eval"), overrides)
    ukf = MakeSimulation(scenario).diagram.GetSubsystemByName("friction_source").ukf
    assert ukf.config.mu_walk_std == 0.1 and ukf.mu0 == 0.6
    assert ukf.config.period_s == scenario.rates.fitter_sample_period_s
    assert ukf.config.process_std == scenario.ukf.process_std
    with pytest.raises(ValueError, match="UkfConfig.mu_walk_std=-1"):
        apply_overrides(scenario, {"ukf.mu_walk_std": -1.0}).validate()


def test_kmpc_switches_the_model_and_bad_overrides_are_named():
    scenario = apply_overrides(load_scenario("paper_eval"), {**SHORT, "estimator": "kmpc"})
    parts = MakeSimulation(scenario)
    nmpc = parts.diagram.GetSubsystemByName("nmpc")
    assert nmpc.controller.config.model == "ks"
    station = parts.diagram.GetSubsystemByName("station")
    assert station.HasOutputPort("true_state") and station.HasOutputPort("state")
    with pytest.raises(ValueError, match="no field 'estimatr'"):
        apply_overrides(scenario, {"estimatr": "ukf"})
    with pytest.raises(ValueError, match="estimator='magic'"):
        simulate_summary("paper_eval", 0, {**SHORT, "estimator": "magic"})


def test_the_run_monitor_stops_at_the_first_failure_on_the_true_state():
    from pydrake.systems.framework import EventStatus

    from pcvfe_drake.control.course import load_course
    from pcvfe_drake.diagrams.run_simulation import FailureMonitor
    from pcvfe_drake.runs.runlog import RunLog

    course = load_course("slalom")
    log = RunLog(None, ["sand"], 2)
    x_on = course.state_on_path(np.array([10.0]), 5.0, 2.5, 1.3)[0]
    x_off = x_on.copy()
    x_off[1] += 6.0  # 6 m beside the path: off the 3 m half width
    monitor = FailureMonitor(None, course, log)
    for k in range(25):  # measured state on the path, the truth off it from row 20 on
        truth = x_off if k >= 20 else x_on
        log.append(k * 0.05, x_on, [0, 0], [0, 0], -1, [0.3, 20, 20], 0.45, 0, true_state=truth)
    status = monitor(None)
    assert status.severity() == EventStatus.Severity.kReachedTermination
    assert monitor.failure.startswith("t=1.00 s") and "left the course" in monitor.failure
