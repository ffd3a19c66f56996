"""Tests of the OracleFriction LeafSystem."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from pcvfe_drake.systems.oracle_friction import OracleFriction
from pcvfe_drake.vehicle.params import ford_escort


def test_copies_the_true_mu_at_its_rate_with_nominal_stiffness():
    params = ford_escort()
    oracle = OracleFriction(params, period_s=0.01)
    sim = Simulator(oracle)
    ctx = sim.get_mutable_context()
    oracle.GetInputPort("true_mu").FixValue(ctx, [0.45])
    sim.Initialize()
    np.testing.assert_allclose(
        oracle.GetOutputPort("theta_hat").Eval(ctx), [0.45, params.C_Sf, params.C_Sr]
    )
    oracle.GetInputPort("true_mu").FixValue(ctx, [0.8])
    assert oracle.GetOutputPort("theta_hat").Eval(ctx)[0] == 0.45  # held until the next update
    sim.AdvanceTo(0.015)
    assert oracle.GetOutputPort("theta_hat").Eval(ctx)[0] == 0.8
    with pytest.raises(ValueError, match="period_s"):
        OracleFriction(params, period_s=0.0)
