"""OracleFriction: the true friction under the car as theta_hat (sim only: the upper bound)."""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import NTHETA


class OracleFriction(LeafSystem):
    """Hands the controller the true mu under the car, with the nominal stiffnesses.

    .. pydrake_system::

        name: OracleFriction
        input_ports:
        - true_mu
        output_ports:
        - theta_hat

    Ports:
        true_mu: input (1), the station's sim-only true friction under the car.
        theta_hat: output (3) ``[mu, C_Sf, C_Sr]`` from discrete state (zero-order hold).

    Rate: a periodic discrete update every ``period_s`` (default 0.01 s, the fitter's sample
    rate, offset 0) copies the true mu; an initialization event does so at t = 0. Only a
    simulated station has ``true_mu``: this source is the upper bound of what a friction
    estimate can give the controller, not an estimator.
    """

    def __init__(self, params: VehicleParams, *, period_s: float = 0.01) -> None:
        super().__init__()
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"OracleFriction: period_s={period_s!r} must be > 0")
        self._stiffness = np.array([params.C_Sf, params.C_Sr])
        self._true_mu_port = self.DeclareVectorInputPort("true_mu", 1)
        self._theta_index = self.DeclareDiscreteState(BasicVector(params.theta))
        self.DeclarePeriodicDiscreteUpdateEvent(
            period_sec=period_s, offset_sec=0.0, update=self._update
        )
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self._theta_port = self.DeclareStateOutputPort("theta_hat", self._theta_index)
        assert self._theta_port.size() == NTHETA

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        mu = float(self._true_mu_port.Eval(context)[0])
        discrete_state.get_mutable_vector(self._theta_index).SetFromVector(
            np.concatenate([[mu], self._stiffness])
        )
