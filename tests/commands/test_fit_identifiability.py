"""``pcvfe fit`` answers only what the data determine: the live estimator's model by default,
and a lower bound marked "not identifiable" where the data never came near the limit."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.commands.fit import default_fit_model
from pcvfe_drake.estimation.fit_answer import distrust, mu_headline
from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
from pcvfe_drake.vehicle.params import ford_escort


@pytest.fixture(scope="module")
def log_path(tmp_path_factory):
    """ST truth, 100 Hz, 6 s each: sand (mu 0.45) in a wide slalom that uses ~0.42 g, brick
    (mu 0.8), 2 s later, in a gentle one that uses ~0.1 g: sand's mu is identifiable, brick's
    is not."""
    params = ford_escort()
    t, s_sand, u_sand = s_curve_drive(params, 0.45, duration_s=6.0, delta_amp_rad=0.15)
    _, s_brick, u_brick = s_curve_drive(params, 0.8, duration_s=6.0, delta_amp_rad=0.04)
    sand = drive_frame(t, s_sand[0], u_sand[0], terrain="sand", mu_true=0.45)
    brick = drive_frame(t + t[-1] + 2.0, s_brick[0], u_brick[0], terrain="brick", mu_true=0.8)
    path = tmp_path_factory.mktemp("ident") / "drive.csv"
    pd.concat([sand, brick]).to_csv(path, index=False)
    return path


def test_headline_is_the_estimate_or_a_bound_that_holds(log_path, capsys):
    assert main(["fit", str(log_path), "--json"]) == 0
    out = capsys.readouterr().out
    report = json.loads(out.strip().splitlines()[-1])
    assert report["context_column"] == "terrain"  # no context column: terrain, as diagnose
    assert report["model"] == "single-track model"
    sand, brick = report["contexts"]["sand"], report["contexts"]["brick"]
    assert sand["identifiable"] and sand["near_limit"]
    assert sand["headline"]["kind"] == "estimate"
    assert abs(sand["headline"]["mu"] - 0.45) < 0.01
    # brick converged (the ST truth's linear tyre gives its mu exactly) but the data used
    # only ~0.1 g of its 0.8: the answer is the bound, not the converged number
    assert brick["converged"] and not brick["near_limit"] and not brick["identifiable"]
    head = brick["headline"]
    assert head["kind"] == "lower_bound" and "mu" not in head
    assert 0.03 < head["mu_at_least"] <= 0.8
    assert brick["mu_interval_95"] == [head["mu_at_least"], None]
    assert "never came near the limit" in head["reason"]


def test_a_fit_below_the_friction_used_is_not_the_friction(tmp_path, capsys):
    """The ST truth's linear tyre has no limit: a slalom at ~0.56 g on mu 0.45 converges on
    0.45, which the car cannot have had; the answer is the friction used."""
    t, states, inputs = s_curve_drive(ford_escort(), 0.45, duration_s=6.0, delta_amp_rad=0.2)
    path = tmp_path / "drive.csv"
    drive_frame(t, states[0], inputs[0]).to_csv(path, index=False)
    assert main(["fit", str(path), "--json"]) == 0
    (entry,) = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["contexts"].values()
    assert entry["converged"] and abs(entry["theta"]["mu"] - 0.45) < 0.01
    assert entry["below_used"] and not entry["identifiable"]
    assert entry["headline"]["kind"] == "lower_bound" and entry["headline"]["mu_at_least"] > 0.5


def test_table_prints_not_identifiable_and_the_fallback_note(log_path, capsys):
    assert main(["fit", str(log_path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("note: fitting the single-track model (no scenario beside the log")
    text = out.splitlines()
    first = next(i for i, ln in enumerate(text) if ln.startswith("friction per context"))
    lines = {ln.split()[0]: ln for ln in text[first + 1 : first + 3]}
    assert lines["sand"].split()[1:3] == ["mu", "="]
    assert "mu >= " in lines["brick"] and "not identifiable" in lines["brick"]
    assert "converged; never near: not identifiable" in out


def test_default_model_is_the_runs_scenario(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "scenario.yaml").write_text(
        "name: x\nvehicle: ford_escort\nestimator: pcvfe\nfitter:\n  near_limit_fraction: 0.5\n"
        "  model:\n    model_error_rel: 0.11\n    effects:\n      - name: peak_tyre\n"
        "        fixed: {k_s: 0.0}\n"
    )
    log = run / "drive_log.csv"
    for where in (log, run):  # the log or its run folder
        model = default_fit_model(where)
        assert [e.name for e in model.effects] == ["peak_tyre"]
        assert model.effects[0].fixed == {"k_s": 0.0}
        assert model.fitter.model_error_rel == 0.11 and model.fitter.near_limit_fraction == 0.5
        assert model.vehicle == "ford_escort" and model.note is None
        assert "effect model" in model.source
    # a shipped scenario named with --scenario wins over the folder's
    shipped = default_fit_model(log, "paper_sim")  # the single-track truth: no effects
    assert shipped.effects == [] and "paper_sim.yaml" in shipped.source
    effects = default_fit_model(tmp_path / "x.csv", "paper_eval")
    assert "peak_tyre" in [e.name for e in effects.effects]
    # nothing beside the log: the single-track model, with a note
    alone = default_fit_model(tmp_path / "x.csv")
    assert alone.effects == [] and "single-track" in alone.note


def test_a_bad_scenario_is_a_named_error(tmp_path, capsys):
    (tmp_path / "scenario.yaml").write_text("fitter:\n  near_limit_fraction: 3\n")
    with pytest.raises(ValueError, match=r"scenario\.yaml: .*fitter: .*near_limit_fraction"):
        default_fit_model(tmp_path / "drive_log.csv")
    (tmp_path / "scenario.yaml").write_text("fitter:\n  no_such_field: 1\n")
    with pytest.raises(ValueError, match=r"scenario\.yaml: .*fitter.*no_such_field"):
        default_fit_model(tmp_path / "drive_log.csv")
    assert main(["fit", str(tmp_path / "drive_log.csv")]) == 2
    assert "no_such_field" in capsys.readouterr().err


def test_headline_words():
    judged = {"mu_lower_bound": 0.31, "near_limit": False, "identifiable": False}
    assert mu_headline(0.93, 0.03, judged)["text"] == "mu >= 0.310, not identifiable"
    near = {"mu_lower_bound": 0.4, "near_limit": True, "identifiable": False, "mu_std_data": 0.07}
    assert mu_headline(0.45, 0.2, near, limit=0.05)["reason"] == (
        "the data leave a std of 0.07, above 0.05"
    )
    peak = {**near, "below_used": True}
    assert "below the friction" in mu_headline(0.35, 0.01, peak)["reason"]
    assert mu_headline(1.05, float("nan"), judged, fitted=False)["kind"] == "no_fit"
    ok = {"mu_lower_bound": 0.4, "near_limit": True, "identifiable": True}
    assert mu_headline(0.45, 0.01, ok) == {
        "kind": "estimate",
        "mu": 0.45,
        "std": 0.01,
        "text": "0.450 +- 0.01",
    }


def test_a_fit_the_quality_checks_reject_is_not_the_friction(tmp_path, capsys):
    """A sign-flipped steering column: the fit converges with mu on its bound."""
    t, states, inputs = s_curve_drive(ford_escort(), 0.45, duration_s=6.0, delta_amp_rad=0.15)
    df = drive_frame(t, states[0], inputs[0])
    df["delta"] = -df["delta"]
    path = tmp_path / "flipped.csv"
    df.to_csv(path, index=False)
    assert main(["fit", str(path), "--lenient", "--json"]) == 0
    (entry,) = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["contexts"].values()
    assert entry["status"] == "converged" and entry["distrust"]
    assert entry["headline"]["kind"] == "lower_bound" and not entry["identifiable"]
    assert "not trustworthy" in entry["headline"]["reason"]


def test_fit_quality_verdicts():
    assert distrust({"at_bound": ["mu"], "loss_noise_ratio": 1.0}) == "mu on its bound"
    assert "loss is 12 x" in distrust({"at_bound": [], "loss_noise_ratio": 12.0})
    poor = {"loss_noise_ratio": 1.0, "fit_percent": {"psi_dot": 30.0, "beta": 90.0}}
    assert distrust(poor) == "poor fit of psi_dot (30 %)"
    good = {"at_bound": [], "loss_noise_ratio": 2.0, "fit_percent": {"psi_dot": 95.0}}
    assert distrust(good) is None
