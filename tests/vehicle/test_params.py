import numpy as np
import pytest
from vehiclemodels.parameters_vehicle1 import parameters_vehicle1

from pcvfe_drake.vehicle.params import (
    PRESETS,
    VehicleParams,
    ford_escort,
    load_vehicle,
    roboracer,
)


def test_ford_escort_from_commonroad():
    p = ford_escort()
    cr = parameters_vehicle1()
    assert p.mu == pytest.approx(1.0489)
    assert p.C_Sf == pytest.approx(20.898, abs=1e-3)
    assert p.C_Sr == p.C_Sf
    assert (p.m, p.I_z, p.lf, p.lr, p.h) == (cr.m, cr.I_z, cr.a, cr.b, cr.h_s)
    assert p.delta_dot_max == 0.4 and p.a_max == 11.5 and p.v_switch == 4.755


def test_roboracer_table_one():
    p = roboracer()
    assert (p.m, p.I_z, p.lf, p.lr, p.h) == (15.32, 0.643, 0.2735, 0.2585, 0.1875)
    assert p.C_Sf == p.C_Sr == 2.0


def test_theta_round_trip():
    p = ford_escort()
    q = p.with_theta([0.3, 10.0, 12.0])
    np.testing.assert_array_equal(q.theta, [0.3, 10.0, 12.0])
    assert q.m == p.m


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("m", -1.0, r"m=-1.0 is outside the physical range \[0.1, 100000\]"),
        ("lf", 0.0, r"lf=0.0 is outside the physical range"),
        ("mu", float("nan"), "mu=nan is not finite"),
        ("delta_min", 1.0, r"delta_min=1.0 is outside the physical range \[-1.6, 0\]"),
        ("delta_min", -0.01, None),
        ("v_min", -1.0, None),
    ],
)
def test_invalid_parameters_are_named(field, value, message):
    if message is None:  # within its range and in order
        assert getattr(ford_escort().replace(**{field: value}), field) == value
        return
    with pytest.raises(ValueError, match=message):
        ford_escort().replace(**{field: value})


def test_load_vehicle_presets_and_files(tmp_path):
    assert load_vehicle(None).name == "ford_escort"
    for name in PRESETS:
        assert load_vehicle(name).name == name
    path = tmp_path / "car.yaml"
    data = roboracer().to_dict()
    data.pop("name")
    data["mu"] = 0.7
    import yaml

    path.write_text(yaml.safe_dump(data))
    car = load_vehicle(path)
    assert car.name == "car" and car.mu == 0.7
    path.write_text("m: 10\nbogus: 3\n")
    with pytest.raises(ValueError, match="unknown vehicle parameter"):
        load_vehicle(path)
    with pytest.raises(ValueError, match="neither a preset"):
        load_vehicle(tmp_path / "missing.yaml")
    assert isinstance(VehicleParams.from_dict(roboracer().to_dict()), VehicleParams)
