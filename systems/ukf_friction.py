"""UkfFriction: the buffer-based baseline, an unscented Kalman filter with mu in its state."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from pcvfe_drake.estimation.ukf import MU, NXA, FrictionUkf, UkfConfig
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import NU, NX


class UkfFriction(LeafSystem):
    """theta_hat from :class:`pcvfe_drake.estimation.ukf.FrictionUkf` (no contexts, no vision).

    .. pydrake_system::

        name: UkfFriction
        input_ports:
        - state
        - actuation
        output_ports:
        - theta_hat
        - filter_state

    Ports:
        state: input (7), the measured ST state.
        actuation: input (2) ``[steer_rate rad/s, accel m/s^2]`` applied to the car.
        theta_hat: output (3) ``[mu, C_Sf, C_Sr]``, the filter's mu with nominal stiffnesses,
            from state (zero-order hold).
        filter_state: output (8 + 64): the filter's mean ``[ST state, mu]`` and covariance
            (row-major), from state.

    Rate: a periodic discrete update every ``config.period_s`` (default 0.01 s, 100 Hz, offset
    0) runs one predict with the actuation held over the last period (read before this
    instant's controller update) and one update with the measured state; an initialization
    event starts the filter at the first measurement. The filter's mean and covariance are the
    discrete state; the filterpy object inside is a workspace, so use one system per vehicle.
    """

    def __init__(self, params: VehicleParams, sigma, config: UkfConfig | None = None) -> None:
        super().__init__()
        self._ukf = FrictionUkf(params, sigma, config)
        cfg = self._ukf.config
        self._stiffness = np.array([params.C_Sf, params.C_Sr])
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._actuation_port = self.DeclareVectorInputPort("actuation", NU)
        x0, p0 = self._ukf.initial(np.zeros(NX))
        self._filter_index = self.DeclareDiscreteState(np.concatenate([x0, p0.ravel()]))
        theta0 = np.concatenate([[self._ukf.mu0], self._stiffness])
        self._theta_index = self.DeclareDiscreteState(BasicVector(theta0))
        self.DeclarePeriodicDiscreteUpdateEvent(
            period_sec=cfg.period_s, offset_sec=0.0, update=self._update
        )
        self.DeclareInitializationDiscreteUpdateEvent(self._init)
        self._theta_port = self.DeclareStateOutputPort("theta_hat", self._theta_index)
        self._filter_port = self.DeclareStateOutputPort("filter_state", self._filter_index)

    @property
    def ukf(self) -> FrictionUkf:
        return self._ukf

    def _write(self, discrete_state: DiscreteValues, x: np.ndarray, p: np.ndarray) -> None:
        discrete_state.get_mutable_vector(self._filter_index).SetFromVector(
            np.concatenate([x, p.ravel()])
        )
        discrete_state.get_mutable_vector(self._theta_index).SetFromVector(
            np.concatenate([[x[MU]], self._stiffness])
        )

    def _init(self, context: Context, discrete_state: DiscreteValues) -> None:
        x, p = self._ukf.initial(self._state_port.Eval(context))
        self._write(discrete_state, x, p)

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        f = context.get_discrete_state(self._filter_index).get_value()
        x, p = f[:NXA], f[NXA:].reshape(NXA, NXA)
        x, p = self._ukf.step(
            x, p, self._actuation_port.Eval(context), self._state_port.Eval(context)
        )
        self._write(discrete_state, x, p)
