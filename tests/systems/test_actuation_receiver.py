"""ActuationReceiver: applies fresh commands, brakes to a stop when they stop."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from pcvfe_drake.lcmtypes import lcmt_vehicle_actuation
from pcvfe_drake.systems.actuation_receiver import ActuationReceiver


def command(utime, steer_rate, accel):
    msg = lcmt_vehicle_actuation()
    msg.utime, msg.steer_rate, msg.accel = utime, steer_rate, accel
    return msg


def test_commands_pass_then_braking_fades_out_at_standstill():
    rx = ActuationReceiver(period_s=0.005, timeout_s=0.1, brake_decel_mps2=4.0)
    sim = Simulator(rx)
    ctx = sim.get_mutable_context()
    port = rx.GetInputPort("message")
    port.FixValue(ctx, AbstractValue.Make(lcmt_vehicle_actuation()))
    x = np.array([0, 0, 0, 5.0, 0, 0, 0])
    rx.GetInputPort("state").FixValue(ctx, x)
    sim.Initialize()
    out = rx.GetOutputPort("actuation")
    np.testing.assert_array_equal(out.Eval(ctx), [0.0, -4.0])  # nothing yet: brake
    port.FixValue(ctx, AbstractValue.Make(command(10_000, 0.2, 1.0)))
    sim.AdvanceTo(0.011)
    np.testing.assert_array_equal(out.Eval(ctx), [0.2, 1.0])
    port.FixValue(ctx, AbstractValue.Make(command(20_000, np.nan, 1.0)))
    sim.AdvanceTo(0.021)
    np.testing.assert_array_equal(out.Eval(ctx), [0.2, 1.0])
    assert rx.GetOutputPort("status").Eval(ctx).last_rejection == "non_finite"
    sim.AdvanceTo(0.2)
    np.testing.assert_array_equal(out.Eval(ctx), [0.0, -4.0])
    x[3] = 0.25
    rx.GetInputPort("state").FixValue(ctx, x)
    np.testing.assert_allclose(out.Eval(ctx), [0.0, -2.0])


def test_a_braking_command_held_at_standstill_does_not_reverse_the_car():
    """Brakes stop a car; a negative acceleration command fades out below 0.5 m/s like the
    watchdog's own braking, so a fallback command held at standstill leaves the car standing."""
    rx = ActuationReceiver(period_s=0.005, timeout_s=0.1, brake_decel_mps2=4.0)
    sim = Simulator(rx)
    ctx = sim.get_mutable_context()
    rx.GetInputPort("message").FixValue(ctx, AbstractValue.Make(command(10_000, 0.1, -5.0)))
    x = np.array([0, 0, 0, 2.0, 0, 0, 0])
    rx.GetInputPort("state").FixValue(ctx, x)
    sim.AdvanceTo(0.006)
    out = rx.GetOutputPort("actuation")
    np.testing.assert_allclose(out.Eval(ctx), [0.1, -5.0])  # at speed: as commanded
    for v, accel in ((0.25, -2.5), (0.0, 0.0), (-0.05, 0.0)):
        x[3] = v
        rx.GetInputPort("state").FixValue(ctx, x)
        np.testing.assert_allclose(out.Eval(ctx), [0.1, accel])
    rx.GetInputPort("message").FixValue(ctx, AbstractValue.Make(command(20_000, 0.0, 1.5)))
    sim.AdvanceTo(0.011)
    np.testing.assert_allclose(out.Eval(ctx), [0.0, 1.5])  # driving off is not faded
