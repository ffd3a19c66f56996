"""The committed Python LCM types are what lcm-gen makes of lcmtypes/*.lcm."""

import importlib.util
import tempfile
from pathlib import Path

import numpy as np

from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation, lcmt_vehicle_state

ROOT = Path(__file__).resolve().parents[1]


def test_generated_python_matches_lcm_gen_output():
    spec = importlib.util.spec_from_file_location("generate", ROOT / "lcmtypes" / "generate.py")
    generate = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generate)
    with tempfile.TemporaryDirectory() as tmp:
        out = generate.generate(Path(tmp))
        names = sorted(p.name for p in out.glob("*.py"))
        assert names == ["__init__.py", "lcmt_vehicle_actuation.py", "lcmt_vehicle_state.py"]
        for name in names:
            committed = ROOT / "pcvfe_drake" / "lcmtypes" / name
            assert committed.read_text() == (out / name).read_text(), (
                f"{committed} is stale: run .venv/bin/python lcmtypes/generate.py"
            )


def test_messages_round_trip():
    msg = lcmt_vehicle_state()
    msg.utime = 1_234_567
    msg.state = [1.0, 2.0, 0.1, 3.0, -0.5, 0.2, 0.01]
    msg.valid = True
    back = lcmt_vehicle_state.decode(msg.encode())
    assert back.utime == msg.utime and back.valid
    np.testing.assert_array_equal(back.state, msg.state)
    act = lcmt_vehicle_actuation()
    act.utime, act.state_utime, act.steer_rate, act.accel = 5, 4, 0.25, -1.5
    back = lcmt_vehicle_actuation.decode(act.encode())
    assert (back.utime, back.state_utime, back.steer_rate, back.accel) == (5, 4, 0.25, -1.5)
