"""The fitter's effect model: files, the car's own constants, where a scenario finds it."""

from __future__ import annotations

import pytest

from pcvfe_drake.models.effect_model import (
    MODEL_DIR,
    EffectModel,
    load_model_file,
    resolve_model,
    vehicle_constants,
    vehicle_model_path,
)
from pcvfe_drake.vehicle.mb_truth import MB_VEHICLES, commonroad_parameters
from pcvfe_drake.vehicle.params import ford_escort, load_vehicle

MAPPINGS = ("lateral_peak", "peak_and_stiffness")


def test_the_cars_own_constants():
    c = vehicle_constants("ford_escort", ford_escort())
    tyre = commonroad_parameters("ford_escort").tire
    assert c["track_slip"] == {"t": commonroad_parameters("ford_escort").T_f}
    assert c["roll_camber"] == {"f0": -tyre.p_vy1, "f1": 0.0, "s0": tyre.p_hy1}
    # a car without a track or a CommonRoad tyre set has none
    assert vehicle_constants("my_car.yaml", ford_escort().replace(track=None)) == {}


def test_model_validation_names_the_problem(tmp_path):
    with pytest.raises(ValueError, match="not both"):
        EffectModel(file="x.yaml", effects=["peak_tyre"])
    with pytest.raises(ValueError, match="model_error_rel must be >= 0"):
        EffectModel(model_error_rel=-0.1)
    with pytest.raises(ValueError, match="std given for 'k_r', which is not held"):
        EffectModel(effects=[{"name": "axle_stiffness", "fixed": {"k_f": 1.0}, "std": {"k_r": 1}}])
    bad = tmp_path / "m.yaml"
    bad.write_text("effects: []\nvalues: 3\n")
    with pytest.raises(ValueError, match=r"m.yaml: unknown key\(s\) \['values'\]"):
        load_model_file(bad)
    bad.write_text("effects: [{name: no_such_effect}]\n")
    with pytest.raises(ValueError, match="m.yaml: .*no_such_effect"):
        load_model_file(bad)
    with pytest.raises(FileNotFoundError, match="model file .*nothing.yaml: no such file"):
        load_model_file(tmp_path / "nothing.yaml")


def test_where_the_model_is_found(tmp_path):
    assert vehicle_model_path("ford_escort", "st", "lateral_peak") is None
    assert vehicle_model_path("bmw_320i", "mb", "lateral_peak") == (
        MODEL_DIR / "bmw_320i_lateral_peak_model.yaml"
    )
    assert vehicle_model_path(str(tmp_path / "car.yaml"), "st", "peak") == tmp_path / (
        "car_model.yaml"
    )
    with pytest.raises(ValueError, match="pcvfe calibrate --simulate ford_escort --mapping peak"):
        resolve_model(EffectModel(), "ford_escort", "mb", "peak")
    assert resolve_model(EffectModel(), "ford_escort", "st", "peak").single_track
    with pytest.raises(ValueError, match="fitter.model.file 'nothing.yaml': no such model file"):
        resolve_model(EffectModel(file="nothing.yaml"), "ford_escort", "mb", "peak")
    inline = EffectModel(effects=["peak_tyre:k_s=0"], model_error_rel=0.1)
    assert resolve_model(inline, "ford_escort", "mb", "peak").to_dict() == inline.to_dict()


@pytest.mark.parametrize("vehicle", sorted(MB_VEHICLES))
@pytest.mark.parametrize("mapping", MAPPINGS)
def test_every_shipped_car_has_a_calibrated_model(vehicle, mapping):
    path = vehicle_model_path(vehicle, "mb", mapping)
    model = load_model_file(path)
    effects = {e.name: e for e in model.effects}
    assert (
        path.read_text()
        .splitlines()[1]
        .startswith(f"# Written by `pcvfe calibrate --simulate {vehicle}")
    )
    assert effects["peak_tyre"].fixed["k_s"] == (1.0 if mapping == "peak_and_stiffness" else 0.0)
    assert effects["track_slip"].fixed["t"] == load_vehicle(vehicle).track
    assert (
        effects["roll_camber"].fixed
        == vehicle_constants(vehicle, load_vehicle(vehicle))["roll_camber"]
    )
    # every parameter is held: the fitter's only unknown is the friction
    assert all(e.fixed for e in model.effects)
    assert 0.0 <= model.model_error_rel < 0.3 and model.calibrated_mu > 0.5


def test_a_vehicle_file_finds_its_model_beside_it(tmp_path):
    car = tmp_path / "car.yaml"
    car.write_text("name: car\n")
    with pytest.raises(ValueError, match="no calibrated model .*car_model.yaml"):
        resolve_model(EffectModel(), str(car), "st", "peak")
    (tmp_path / "car_model.yaml").write_text(
        "vehicle: car\neffects: [{name: peak_tyre, fixed: {k_s: 0.5}}]\nmodel_error_rel: 0.07\n"
    )
    model = resolve_model(EffectModel(), str(car), "st", "peak")
    assert model.effects[0].fixed == {"k_s": 0.5} and model.model_error_rel == 0.07


def test_scenarios_get_the_cars_model_or_the_papers_fitter():
    import dataclasses

    from pcvfe_drake.diagrams.scenario_io import load_scenario

    paper_eval = load_scenario("paper_eval")
    calibrated = load_model_file(vehicle_model_path("ford_escort", "mb", "lateral_peak"))
    assert paper_eval.fitter.model.single_track  # the scenario holds no constant of its own
    assert paper_eval.fit_config().model.to_dict() == calibrated.to_dict()
    paper = dataclasses.replace(paper_eval, estimator="pcvfe_paper")
    assert paper.fit_config().model.single_track and not paper.fit_config().effects
    assert load_scenario("paper_sim").fit_config().model.single_track
    overlay = MODEL_DIR.parent / "scenarios" / "overlays" / "bmw_320i.yaml"
    bmw = load_scenario("paper_eval", overlay).fit_config().model
    assert (
        bmw.to_dict() == load_model_file(MODEL_DIR / "bmw_320i_lateral_peak_model.yaml").to_dict()
    )
