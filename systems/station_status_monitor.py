"""StationStatusMonitor: one ``station_status`` from the receivers' watchdog bookkeeping."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem

from pcvfe_drake.hardware.watchdog import StationStatus, StreamStatus, stream_condition


class StationStatusMonitor(LeafSystem):
    """Says whether the hardware station's outputs are live, and if not, why.

    .. pydrake_system::

        name: StationStatusMonitor
        input_ports:
        - state_status
        - camera_status
        output_ports:
        - station_status

    Ports:
        state_status, camera_status: inputs, abstract
            :class:`pcvfe_drake.hardware.watchdog.StreamStatus` of the state and camera
            receivers.
        station_status: output, abstract :class:`pcvfe_drake.hardware.watchdog.StationStatus`
            (``source="lcm"``): each stream's condition at the context time (``ok``,
            ``waiting``, ``timeout``) and its counts; ``reason()`` is a one-line explanation.

    A pure output calc of the inputs and the time (no state, no events).
    """

    def __init__(self, *, state_timeout_s: float, camera_timeout_s: float) -> None:
        super().__init__()
        self.state_timeout_s = float(state_timeout_s)
        self.camera_timeout_s = float(camera_timeout_s)
        model = AbstractValue.Make(StreamStatus())
        self._state_port = self.DeclareAbstractInputPort("state_status", model)
        self._camera_port = self.DeclareAbstractInputPort("camera_status", model)
        self.DeclareAbstractOutputPort(
            "station_status", lambda: AbstractValue.Make(StationStatus()), self._calc
        )

    def _calc(self, context: Context, output: AbstractValue) -> None:
        t = context.get_time()
        state = self._state_port.Eval(context)
        camera = self._camera_port.Eval(context)
        output.set_value(
            StationStatus(
                state=stream_condition(state, t, self.state_timeout_s),
                camera=stream_condition(camera, t, self.camera_timeout_s),
                streams=(state, camera),
                source="lcm",
            )
        )
