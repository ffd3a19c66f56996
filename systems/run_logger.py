"""RunLogger: samples the closed loop into a RunLog (drive log written as the run goes)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.runs.runlog import RunLog
from pcvfe_drake.vehicle.single_track import NTHETA, NU, NX


class RunLogger(LeafSystem):
    """Appends one row per period to a :class:`pcvfe_drake.runs.runlog.RunLog`.

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
        - true_state
        - image

    All inputs are read at the publish only (no output, no state). ``image`` (abstract
    ``ImageRgba8U``) is optional: when connected, a frame is saved every
    ``run_log.frame_period_s`` for the paper's Fig. 4. ``true_mu`` and ``true_terrain`` are the
    station's sim-only truth ports, optional too: unconnected (a hardware or replay station) the
    rows have ``mu_true`` NaN and no terrain. A row whose ``state`` is not finite (a hardware
    station whose state stream is lost) is not a measurement: it is skipped and counted in
    ``skipped_rows``, so the drive log on disk stays valid.
    ``true_state`` (7, sim-only, optional) is the true state, logged as the ``true_sx`` ...
    ``true_beta`` columns when connected (``state`` is then the measured one).

    Rate: one periodic publish event every ``period_s`` (the scenario's log period), and with
    ``sample_period_s`` a second one at that period (the fitter's sampling) that keeps the
    ``state`` and the ``actuation`` it reads (``RunLog.add_sample``: the values the fitter's
    update at the same instant reads, since a publish at t sees the state before the updates at
    t), so a replay can feed the fitter exactly what it had. The RunLog
    is the run's output sink, owned by the caller (its rows are written to disk in chunks, so an
    interrupted run keeps what it had); call :meth:`finish` and then ``run_log.close()`` after
    the last AdvanceTo.

    Input timing: a publish at time t runs before the discrete and unrestricted updates at t, so
    the ``actuation`` it reads is the one held over the period *before* t. The drive-log format
    pairs each row's state with the input applied *from* it (what an offline fit rolls out), so
    each row is held back one period and written at the next publish, with the actuation read
    there (with ``period_s`` equal to the controller's period that is exactly the input held from
    the row to the next). :meth:`finish` writes the last row with the actuation at its own time
    (the input held into it: the next one is not computed yet). Every other column is read at
    the row's own time.
    """

    def __init__(
        self, run_log: RunLog, period_s: float, *, sample_period_s: float | None = None
    ) -> None:
        super().__init__()
        for name, value in (("period_s", period_s), ("sample_period_s", sample_period_s)):
            if value is not None and not (np.isfinite(value) and value > 0):
                raise ValueError(f"RunLogger: {name} must be > 0, got {value!r}")
        self.run_log = run_log
        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._actuation_port = self.DeclareVectorInputPort("actuation", NU)
        self._features_port = self.DeclareVectorInputPort("features", run_log.feature_dim)
        self._context_port = self.DeclareVectorInputPort("context_id", 1)
        self._theta_port = self.DeclareVectorInputPort("theta_hat", NTHETA)
        self._true_mu_port = self.DeclareVectorInputPort("true_mu", 1)
        self._true_terrain_port = self.DeclareVectorInputPort("true_terrain", 1)
        self._true_state_port = self.DeclareVectorInputPort("true_state", NX)
        self._image_port = self.DeclareAbstractInputPort("image", AbstractValue.Make(ImageRgba8U()))
        self.DeclarePeriodicPublishEvent(period_sec=period_s, offset_sec=0.0, publish=self._log)
        if sample_period_s is not None:
            self.DeclarePeriodicPublishEvent(
                period_sec=sample_period_s, offset_sec=0.0, publish=self._sample
            )
        # The row waiting for the input applied from it (see "Input timing"); an output sink's
        # bookkeeping like the RunLog itself, not part of the simulated state.
        self._held_row: dict | None = None
        self.skipped_rows = 0
        """Rows not written because their state was not finite."""

    def _log(self, context) -> None:
        actuation = np.array(self._actuation_port.Eval(context), dtype=float)
        self._write_held(actuation)
        t = context.get_time()
        image = None
        if self._image_port.HasValue(context) and self.run_log.wants_frame(t):
            image = np.array(self._image_port.Eval(context).data)
        self._held_row = {
            "t_s": t,
            "state": np.array(self._state_port.Eval(context), dtype=float),
            "actuation": actuation,
            "features": np.array(self._features_port.Eval(context), dtype=float),
            "context_id": float(self._context_port.Eval(context)[0]),
            "theta_hat": np.array(self._theta_port.Eval(context), dtype=float),
            "mu_true": self._optional(self._true_mu_port, context, np.nan),
            "terrain_index": self._optional(self._true_terrain_port, context, -1.0),
            "true_state": (
                np.array(self._true_state_port.Eval(context), dtype=float)
                if self._true_state_port.HasValue(context)
                else None
            ),
            "image_rgb": image,
        }

    def _sample(self, context) -> None:
        self.run_log.add_sample(
            context.get_time(),
            self._state_port.Eval(context),
            self._actuation_port.Eval(context),
        )

    @staticmethod
    def _optional(port, context, default: float) -> float:
        return float(port.Eval(context)[0]) if port.HasValue(context) else default

    def _write_held(self, actuation: np.ndarray | None) -> None:
        row, self._held_row = self._held_row, None
        if row is None:
            return
        if not np.all(np.isfinite(row["state"])):
            self.skipped_rows += 1
            return
        if actuation is not None:
            row["actuation"] = actuation
        self.run_log.append(**row)

    def finish(self) -> None:
        """Write the row still held back (the last one) with the actuation read at its time.
        Call after the last AdvanceTo, before ``run_log.close()``; idempotent."""
        self._write_held(None)
