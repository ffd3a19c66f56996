"""Tests of the LookupFriction LeafSystem."""

import numpy as np
from pydrake.systems.analysis import Simulator

from pcvfe_drake.estimation.lookup import table_from_features
from pcvfe_drake.systems.lookup_friction import LookupFriction
from pcvfe_drake.vehicle.params import ford_escort

TABLE = table_from_features(
    {"a": np.array([[0.0, 0.0], [0.1, 0.0]]), "b": np.array([[1.0, 1.0], [1.1, 1.0]])},
    {"a": 0.3, "b": 0.7},
    default_mu=0.25,
)


def test_classifies_each_frame_and_falls_back_on_unknown_ones():
    params = ford_escort()
    system = LookupFriction(TABLE, params, period_s=0.1, offset_s=0.001)
    sim = Simulator(system)
    ctx = sim.get_mutable_context()
    port = system.GetInputPort("features")
    port.FixValue(ctx, [1.02, 1.0])
    sim.Initialize()
    np.testing.assert_allclose(
        system.GetOutputPort("theta_hat").Eval(ctx), [0.7, params.C_Sf, params.C_Sr]
    )
    assert system.GetOutputPort("terrain_class").Eval(ctx)[0] == 1
    port.FixValue(ctx, [0.05, 0.0])
    sim.AdvanceTo(0.0005)
    assert system.GetOutputPort("theta_hat").Eval(ctx)[0] == 0.7  # not yet: next frame at 0.001
    sim.AdvanceTo(0.002)
    assert system.GetOutputPort("theta_hat").Eval(ctx)[0] == 0.3
    port.FixValue(ctx, [5.0, -5.0])
    sim.AdvanceTo(0.1)
    assert system.GetOutputPort("theta_hat").Eval(ctx)[0] == 0.3  # held between frames
    sim.AdvanceTo(0.102)
    assert system.GetOutputPort("theta_hat").Eval(ctx)[0] == 0.25
    assert system.GetOutputPort("terrain_class").Eval(ctx)[0] == -1
