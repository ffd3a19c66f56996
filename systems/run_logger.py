"""RunLogger: samples the closed loop into a RunLog (drive log written as the run goes)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.runlog import RunLog
from pcvfe_drake.vehicle import NTHETA, NU, NX


class RunLogger(LeafSystem):
    """Appends one row per period to a :class:`pcvfe_drake.runlog.RunLog`.

    .. pydrake_system::

        name: RunLogger
        input_ports:
        - state
        - actuation
        - features
        - context_id
        - theta_hat
        - true_mu
        - true_terrain
        - image

    All inputs are read at the publish only (no output, no state). ``image`` (abstract
    ``ImageRgba8U``) is optional: when connected, a frame is saved every
    ``run_log.frame_period_s`` for the paper's Fig. 4. ``true_mu`` and ``true_terrain`` are the
    plant's sim-only truth ports.

    Rate: one periodic publish event every ``period_s`` (the scenario's log period). The RunLog
    is the run's output sink, owned by the caller (its rows are written to disk in chunks, so an
    interrupted run keeps what it had); call ``run_log.close()`` after the last AdvanceTo.
    """

    def __init__(self, run_log: RunLog, period_s: float) -> None:
        super().__init__()
        if not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"RunLogger: period_s must be > 0, got {period_s!r}")
        self.run_log = run_log
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._actuation_port = self.DeclareVectorInputPort("actuation", NU)
        self._features_port = self.DeclareVectorInputPort("features", run_log.feature_dim)
        self._context_port = self.DeclareVectorInputPort("context_id", 1)
        self._theta_port = self.DeclareVectorInputPort("theta_hat", NTHETA)
        self._true_mu_port = self.DeclareVectorInputPort("true_mu", 1)
        self._true_terrain_port = self.DeclareVectorInputPort("true_terrain", 1)
        self._image_port = self.DeclareAbstractInputPort("image", AbstractValue.Make(ImageRgba8U()))
        self.DeclarePeriodicPublishEvent(period_sec=period_s, offset_sec=0.0, publish=self._log)

    def _log(self, context) -> None:
        t = context.get_time()
        image = None
        if self._image_port.HasValue(context) and self.run_log.wants_frame(t):
            image = np.asarray(self._image_port.Eval(context).data)
        self.run_log.append(
            t,
            self._state_port.Eval(context),
            self._actuation_port.Eval(context),
            self._features_port.Eval(context),
            float(self._context_port.Eval(context)[0]),
            self._theta_port.Eval(context),
            float(self._true_mu_port.Eval(context)[0]),
            float(self._true_terrain_port.Eval(context)[0]),
            image,
        )
