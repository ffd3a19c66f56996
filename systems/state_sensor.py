"""StateSensor: the car's INS/GNSS + IMU + steering encoder, turning the true state into `state`."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from pcvfe_drake.vehicle.sensing import SensingConfig, StateSensorModel
from pcvfe_drake.vehicle.single_track import NX


class StateSensor(LeafSystem):
    """Measured ST state from the true one (``pcvfe_drake.vehicle.sensing``).

    .. pydrake_system::

        name: StateSensor
        input_ports:
        - true_state
        output_ports:
        - state

    Ports:
        true_state: input (7), the plant's true ST state ``[sx, sy, delta, v, psi, psi_dot,
            beta]`` (SI units).
        state: output (7), ``x_true(t - latency) + bias + n_k`` with the noise ``n_k`` of sensor
            sample ``k = floor(t / period_s)`` drawn from ``default_rng([seed, 7, k])``.

    Rate and timing: without latency the output is computed from the input (direct
    feedthrough; the plant's state output has none, so no loop) with the noise held per sensor
    sample: consumers that sample at multiples of ``period_s`` (fitter 100 Hz, NMPC and logger
    20 Hz) read the state of that instant. With ``latency_s`` > 0 a periodic discrete update
    every ``period_s`` (offset 0) stores the true state in a ring of ``latency_steps`` samples
    (discrete state, filled with the initial state at initialization) and the output is the
    oldest sample: at ``t_k`` (before that instant's updates) the state of ``t_(k - n)``.
    """

    def __init__(self, config: SensingConfig, seed: int = 0) -> None:
        super().__init__()
        self._model = StateSensorModel(config, seed)
        self._n = config.latency_steps
        self._true_port = self.DeclareVectorInputPort("true_state", NX)
        if self._n > 0:
            self._ring = self.DeclareDiscreteState(np.zeros(NX * self._n))
            self.DeclarePeriodicDiscreteUpdateEvent(
                period_sec=config.period_s, offset_sec=0.0, update=self._on_sample
            )
            self.DeclareInitializationDiscreteUpdateEvent(self._on_init)
            self._state_port = self.DeclareVectorOutputPort(
                "state", NX, self._calc_delayed, prerequisites_of_calc={self.xd_ticket()}
            )
        else:
            self._state_port = self.DeclareVectorOutputPort("state", NX, self._calc_now)

    @property
    def model(self) -> StateSensorModel:
        return self._model

    def _calc_now(self, context: Context, output: BasicVector) -> None:
        x = self._true_port.Eval(context)
        output.SetFromVector(self._model.measure(x, context.get_time()))

    def _calc_delayed(self, context: Context, output: BasicVector) -> None:
        ring = context.get_discrete_state(self._ring).get_value()
        output.SetFromVector(self._model.measure(ring[:NX], context.get_time()))

    def _on_init(self, context: Context, discrete_state: DiscreteValues) -> None:
        x = np.asarray(self._true_port.Eval(context), dtype=float)
        discrete_state.get_mutable_vector(self._ring).SetFromVector(np.tile(x, self._n))

    def _on_sample(self, context: Context, discrete_state: DiscreteValues) -> None:
        ring = context.get_discrete_state(self._ring).get_value()
        x = np.asarray(self._true_port.Eval(context), dtype=float)
        discrete_state.get_mutable_vector(self._ring).SetFromVector(np.concatenate([ring[NX:], x]))
