"""StationStatusMonitor: conditions at the context time from the receivers' bookkeeping."""

from pydrake.common.value import AbstractValue

from pcvfe_drake.hardware.watchdog import StreamStatus, check_message
from pcvfe_drake.systems.station_status_monitor import StationStatusMonitor


def test_conditions_follow_the_timeouts():
    monitor = StationStatusMonitor(state_timeout_s=0.05, camera_timeout_s=0.3)
    ctx = monitor.CreateDefaultContext()
    state, _ = check_message(StreamStatus(name="state"), 1.0, 1, max_delay_s=0.1)
    monitor.GetInputPort("state_status").FixValue(ctx, AbstractValue.Make(state))
    monitor.GetInputPort("camera_status").FixValue(
        ctx, AbstractValue.Make(StreamStatus(name="camera"))
    )
    ctx.SetTime(1.04)
    status = monitor.GetOutputPort("station_status").Eval(ctx)
    assert (status.state, status.camera, status.source) == ("ok", "waiting", "lcm")
    ctx.SetTime(1.06)
    status = monitor.GetOutputPort("station_status").Eval(ctx)
    assert status.state == "timeout" and not status.ok
    assert status.reason() == "state timeout; camera waiting"
