"""Tests of the StateSensor LeafSystem (measured state from the true one)."""

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, Integrator

from pcvfe_drake.systems.state_sensor import StateSensor
from pcvfe_drake.vehicle.sensing import SensingConfig, StateSensorModel

X = np.array([1.0, 2.0, 0.01, 5.0, 0.3, 0.1, 0.02])


def test_noise_free_is_the_truth_and_noise_matches_the_core_model():
    clean = StateSensor(SensingConfig(model="none"))
    ctx = clean.CreateDefaultContext()
    clean.get_input_port(0).FixValue(ctx, X)
    np.testing.assert_array_equal(clean.GetOutputPort("state").Eval(ctx), X)

    cfg = SensingConfig(model="ins", bias=[0.1, 0, 0, 0, 0, 0, 0])
    noisy = StateSensor(cfg, seed=4)
    ctx = noisy.CreateDefaultContext()
    noisy.get_input_port(0).FixValue(ctx, X)
    ctx.SetTime(0.125)
    y = noisy.GetOutputPort("state").Eval(ctx)
    np.testing.assert_array_equal(y, StateSensorModel(cfg, seed=4).measure(X, 0.125))
    assert abs(y[0] - X[0] - 0.1) < 5 * cfg.sx_m and not np.array_equal(y, X)


def test_latency_delays_a_ramp_by_whole_samples():
    """A ramp x(t) = t (all states) through a 30 ms latency reads x(t - 0.03) at t = 0.5."""
    builder = DiagramBuilder()
    ramp = builder.AddNamedSystem("ramp", Integrator(7))
    one = builder.AddNamedSystem("one", ConstantVectorSource(np.ones(7)))
    sigmas = ("sx_m", "sy_m", "delta_rad", "v_mps", "psi_rad", "psi_dot_radps", "beta_rad")
    cfg = SensingConfig(model="ins", latency_s=0.03, **dict.fromkeys(sigmas, 0.0))
    sensor = builder.AddNamedSystem("sensor", StateSensor(cfg))
    builder.Connect(one.get_output_port(), ramp.get_input_port())
    builder.Connect(ramp.get_output_port(), sensor.GetInputPort("true_state"))
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(0.5)
    ctx = sensor.GetMyContextFromRoot(sim.get_context())
    np.testing.assert_allclose(sensor.GetOutputPort("state").Eval(ctx), np.full(7, 0.47), atol=1e-9)
