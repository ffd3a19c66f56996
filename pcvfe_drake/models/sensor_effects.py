"""Sensor-error effects: the vehicle is the ST model, but the sensors report something else.

They use the measurement hooks of :class:`~pcvfe_drake.models.effects.Effect`: ``measure``
maps a predicted (true) state to what the sensor would report, and ``unmeasure`` turns the
measured state a rollout starts from back into the true one. A sensor error therefore changes
both the start of every window and every compared sample, as it does on a real car.

* ``gyro_bias``: the yaw-rate gyro reads ``psi_dot + b``;
* ``speed_scale``: the speed sensor reads ``k v`` (wheel-radius or calibration error);
* ``steering_offset``: the steering encoder reads the road-wheel angle minus ``d0`` (so the
  wheels stand at the measured angle plus ``d0``).
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.models.effects import Effect, EffectParam, register_effect
from pcvfe_drake.vehicle.single_track import DELTA, PSI_DOT, V


def _with_column(y: np.ndarray, col: int, values: np.ndarray) -> np.ndarray:
    out = np.array(y, dtype=float, copy=True)
    out[..., col] = values
    return out


class GyroBias(Effect):
    """A constant bias of the yaw-rate gyro: it reads ``psi_dot + b``."""

    name = "gyro_bias"
    description = "yaw-rate gyro bias, psi_dot_measured = psi_dot + b"
    params = (EffectParam("b", "rad/s", -0.1, 0.1, 0.0, 0.002, 0.0, "gyro bias"),)
    measurement = True
    signature_state = "psi_dot"
    signature_label = "a constant"

    def measure(self, y, p):
        return _with_column(y, PSI_DOT, y[..., PSI_DOT] + p["b"])

    def unmeasure(self, y, p):
        return _with_column(y, PSI_DOT, y[..., PSI_DOT] - p["b"])


class SpeedScale(Effect):
    """A scale-factor error of the speed sensor: it reads ``k v`` (e.g. a tyre radius that
    differs from the calibrated one)."""

    name = "speed_scale"
    description = "speed-sensor scale factor, v_measured = k v"
    params = (EffectParam("k", "-", 0.8, 1.25, 1.0, 0.01, 1.0, "speed scale factor"),)
    measurement = True
    starts = ((0.97,), (1.03,))
    signature_state = "v"
    signature_label = "acceleration command"

    def measure(self, y, p):
        return _with_column(y, V, y[..., V] * p["k"])

    def unmeasure(self, y, p):
        return _with_column(y, V, y[..., V] / p["k"])

    def signature_regressors(self, data):
        return data.u[:, 1:2]


class SteeringOffset(Effect):
    """A constant offset of the steering encoder: the wheels stand at the measured angle plus
    ``d0`` (the encoder reads the true angle minus ``d0``)."""

    name = "steering_offset"
    description = "steering-encoder offset, delta_wheel = delta_measured + d0"
    params = (EffectParam("d0", "rad", -0.1, 0.1, 0.0, 0.005, 0.0, "steering offset"),)
    measurement = True
    signature_state = "psi_dot"
    signature_label = "a constant"

    def measure(self, y, p):
        return _with_column(y, DELTA, y[..., DELTA] - p["d0"])

    def unmeasure(self, y, p):
        return _with_column(y, DELTA, y[..., DELTA] + p["d0"])


for _cls in (GyroBias, SpeedScale, SteeringOffset):
    register_effect(_cls)
