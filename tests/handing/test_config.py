"""The handing's typed, nested settings: defaults, tagged variants, and errors naming the
field."""

import math
import sys
from pathlib import Path

import pytest

from pcvfe_drake.estimation.live_fit_config import LiveFitConfig
from pcvfe_drake.estimation.probe import ProbeSettings
from pcvfe_drake.handing.config import (
    Conservative,
    Estimate,
    HandingConfig,
    LowerBound,
    Probe,
    StatedFloor,
)
from pcvfe_drake.handing.context_state import ModelError
from pcvfe_drake.models.effect_model import EffectModel

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def test_defaults_and_invalid_fields_are_named():
    cfg = HandingConfig()
    assert isinstance(cfg.unknown, Conservative) and isinstance(cfg.unidentified, Estimate)
    assert cfg.confirm_rise_s == 1.0 and not cfg.probing and not cfg.floor_stated
    bad = [
        ({"floor_mu": 0.0}, "HandingConfig.floor_mu"),
        ({"confirm_rise_s": math.nan}, "HandingConfig.confirm_rise_s"),
        ({"noise_hold_s": -1.0}, "HandingConfig.noise_hold_s"),
        ({"unknown": "conservative"}, "HandingConfig.unknown"),
        ({"unidentified": Probe(hold_s=0.0)}, "HandingConfig.unidentified.hold_s"),
        ({"unknown": Conservative(sigmas=-1.0)}, "HandingConfig.unknown.sigmas"),
    ]
    for kwargs, match in bad:
        with pytest.raises(ValueError, match=match):
            HandingConfig(**kwargs)
    with pytest.raises(ValueError, match="calibrated_mu must be"):
        ModelError(0.1, (0.8, 0.3))
    # the calibration surface's friction comes from the car's model file
    cfg = LiveFitConfig(model=EffectModel(model_error_rel=0.05, calibrated_mu=1.0))
    assert cfg.model_error().calibrated_mu == (1.0, 1.0)
    assert cfg.model_error().rel_at(0.5) == pytest.approx(0.1)


def test_probe_numbers_derive_from_the_planners_share():
    # the linear ratio is a bend peaking at the planner's share, the limit one 25 % overshoot
    default = ProbeSettings(use_fraction=0.64)
    assert default.linear_ratio == pytest.approx(1.14, abs=0.005)
    assert default.bend_limit == pytest.approx(1.26, abs=0.005)
    greedy = ProbeSettings(use_fraction=0.81)
    assert greedy.linear_ratio < greedy.bend_limit
    assert greedy.linear_ratio > default.linear_ratio
    with pytest.raises(ValueError, match="planner's share"):
        ProbeSettings(use_fraction=1.5)


def test_scenario_files_take_tagged_variants_and_a_saved_scenario_loads_again(tmp_path):
    from diagrams.scenario_io import scenario_from_yaml_text

    text = (
        "fitter:\n  handing:\n    floor_mu: 0.2\n    unknown: !StatedFloor {}\n"
        "    unidentified: !LowerBound {}\n"
    )
    s = scenario_from_yaml_text(text)
    h = s.fitter.handing
    assert h.floor_mu == 0.2 and isinstance(h.unknown, StatedFloor)
    assert isinstance(h.unidentified, LowerBound)
    again = scenario_from_yaml_text(s.to_yaml())
    assert again.fitter.handing == h
    with pytest.raises(ValueError, match=r"fitter.handing.unknown.*!Hope"):
        scenario_from_yaml_text("fitter: {handing: {unknown: !Hope {}}}")
    with pytest.raises(ValueError, match="fitter.handing.unidentified.max_exces"):
        scenario_from_yaml_text("fitter: {handing: {unidentified: !Probe {max_exces: 1}}}")
    # the old flat fields say where they went
    with pytest.raises(ValueError, match=r"'fitter.rise_confirm_s' is now handing.confirm_rise_s"):
        scenario_from_yaml_text("fitter: {rise_confirm_s: 1.0}")
