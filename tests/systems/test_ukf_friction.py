"""Tests of the UkfFriction LeafSystem on a planted single-terrain drive."""

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from pcvfe_drake.estimation.ukf import MU, NXA
from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.systems.ukf_friction import UkfFriction
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort


def test_estimates_mu_of_a_replayed_drive():
    params = ford_escort()
    noise = MeasurementNoise()
    t, S, U = s_curve_drive(params, [0.45], duration_s=8.0, speed_mps=8.0)
    Z = noise.apply(S[0], np.random.default_rng(0))
    builder = DiagramBuilder()
    # Zero-order holds of the logged measurement and input (each sample held to the next).
    zs = builder.AddNamedSystem("z", TrajectorySource(PiecewisePolynomial.ZeroOrderHold(t, Z.T)))
    us = builder.AddNamedSystem("u", TrajectorySource(PiecewisePolynomial.ZeroOrderHold(t, U[0].T)))
    ukf = builder.AddNamedSystem("ukf", UkfFriction(params, noise.sigma))
    builder.Connect(zs.get_output_port(), ukf.GetInputPort("state"))
    builder.Connect(us.get_output_port(), ukf.GetInputPort("actuation"))
    diagram = builder.Build()
    sim = Simulator(diagram)
    ctx = ukf.GetMyContextFromRoot(sim.get_mutable_context())
    sim.Initialize()
    assert ukf.GetOutputPort("theta_hat").Eval(ctx)[0] == params.mu
    sim.AdvanceTo(7.9)
    theta = ukf.GetOutputPort("theta_hat").Eval(ctx)
    assert abs(theta[0] - 0.45) < 0.05, theta
    f = ukf.GetOutputPort("filter_state").Eval(ctx)
    assert f.size == NXA + NXA * NXA and f[MU] == theta[0]
