"""LookupFriction: the lookup-table baseline (terrain class from the image, mu from a table)."""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from pcvfe_drake.estimation.lookup import UNKNOWN_CLASS, LookupTable
from pcvfe_drake.vehicle.params import VehicleParams


class LookupFriction(LeafSystem):
    """theta_hat from the terrain class of the current camera frame (``estimation.lookup``).

    .. pydrake_system::

        name: LookupFriction
        input_ports:
        - features
        output_ports:
        - theta_hat
        - terrain_class

    Ports:
        features: input (D), the pipeline's information vector of the current frame
            (``ClipFeatures``), the feature space the table's prototypes were made in.
        theta_hat: output (3) ``[mu, C_Sf, C_Sr]``: the table's mu of the frame's class (its
            ``default_mu`` when the frame is unknown), nominal stiffnesses; from state.
        terrain_class: output (1), the class index in ``table.classes`` (-1: unknown); logged
            as the run's ``context`` column.

    Rate: a periodic discrete update every ``period_s`` at ``offset_s`` (the camera period and
    the clustering's frame offset: each frame is classified just after it is taken); an
    initialization event classifies the first frame.
    """

    def __init__(
        self,
        table: LookupTable,
        params: VehicleParams,
        *,
        period_s: float = 0.1,
        offset_s: float = 0.0,
    ) -> None:
        super().__init__()
        if not (math.isfinite(period_s) and period_s > 0 and 0 <= offset_s < period_s):
            raise ValueError(
                f"LookupFriction: period_s={period_s!r} must be > 0 and offset_s={offset_s!r} "
                "in [0, period_s)"
            )
        self.table = table
        self._stiffness = np.array([params.C_Sf, params.C_Sr])
        self._features_port = self.DeclareVectorInputPort("features", table.dim)
        theta0 = np.concatenate([[table.default_mu], self._stiffness])
        self._theta_index = self.DeclareDiscreteState(BasicVector(theta0))
        self._class_index = self.DeclareDiscreteState(BasicVector([float(UNKNOWN_CLASS)]))
        self.DeclarePeriodicDiscreteUpdateEvent(
            period_sec=period_s, offset_sec=offset_s, update=self._update
        )
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self._theta_port = self.DeclareStateOutputPort("theta_hat", self._theta_index)
        self._class_port = self.DeclareStateOutputPort("terrain_class", self._class_index)

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        k, _ = self.table.classify(self._features_port.Eval(context))
        mu = self.table.default_mu if k == UNKNOWN_CLASS else self.table.mu[k]
        discrete_state.get_mutable_vector(self._theta_index).SetFromVector(
            np.concatenate([[mu], self._stiffness])
        )
        discrete_state.get_mutable_vector(self._class_index).SetAtIndex(0, float(k))
