"""The car's state sensing: what an INS/GNSS + IMU + steering encoder reports (no pydrake).

The simulated station's ``state`` output is the *measured* state, produced from the plant's true
state by :class:`StateSensorModel`; the true state stays available as the sim-only
``true_state``. Model (``SensingConfig.model = "ins"``), per state in the ST order
``[sx, sy, delta, v, psi, psi_dot, beta]``::

    y(t) = x_true(t - latency_s) + bias + n_k,  n_k ~ N(0, diag(sigma^2)),  k = floor(t / period_s)

* ``n_k`` is white Gaussian noise drawn per sensor sample (``period_s``, 100 Hz by default, the
  public simulator's state rate) from ``numpy.random.default_rng([seed, SENSING_STREAM, k])``: a
  pure function of the scenario's seed and the sample index, held over the sample period;
* ``bias`` is a constant offset per state (e.g. a steering-encoder zero error);
* ``latency_s`` delays the true state by a whole number of sensor periods (rounded).

The default standard deviations are those of
:class:`pcvfe_drake.models.synthetic_drive.MeasurementNoise` (RTK GNSS position 2 cm,
dual-antenna heading 0.5 deg, gyro 0.01 rad/s, slip angle 0.005 rad,
speed 0.05 m/s, steering encoder 0.002 rad). ``model = "none"`` reports the true state
unchanged (the behaviour before sensing existed). This module has no ``from __future__ import
annotations``: the scenario loader reads :class:`SensingConfig`'s field types.
"""

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.seed_streams import SeededNormals
from pcvfe_drake.vehicle.single_track import NX, STATE_NAMES

SENSING_MODELS = ("none", "ins")
"""``none``: the true state; ``ins``: noise, bias and latency as in the module docstring."""
SENSING_STREAM = 7
"""Second element of the noise generator's seed sequence (keeps it apart from the camera's)."""

_DEFAULT = MeasurementNoise()


@dataclass
class SensingConfig:
    """State sensing of the simulated car (units in the names; see the module docstring)."""

    model: str = "none"
    """``none`` (true state) or ``ins`` (noise, bias, latency)."""
    period_s: float = 0.01
    """Sensor sample period [s] (noise held per sample; latency counted in samples)."""
    latency_s: float = 0.0
    """Delay of the measurement behind the truth [s], rounded to whole sample periods."""
    sx_m: float = _DEFAULT.sx_m
    sy_m: float = _DEFAULT.sy_m
    delta_rad: float = _DEFAULT.delta_rad
    v_mps: float = _DEFAULT.v_mps
    psi_rad: float = _DEFAULT.psi_rad
    psi_dot_radps: float = _DEFAULT.psi_dot_radps
    beta_rad: float = _DEFAULT.beta_rad
    bias: list[float] = field(default_factory=lambda: [0.0] * NX)
    """Constant offset per state, ST order, SI units."""

    @property
    def noise(self) -> MeasurementNoise:
        """The standard deviations as a ``MeasurementNoise`` (its fields, by name)."""
        return MeasurementNoise(
            **{f.name: getattr(self, f.name) for f in dataclasses.fields(MeasurementNoise)}
        )

    @property
    def enabled(self) -> bool:
        return self.model != "none"

    @property
    def latency_steps(self) -> int:
        """Latency in whole sensor samples."""
        return int(round(self.latency_s / self.period_s))

    def problems(self, prefix: str = "sensing") -> list[str]:
        """Every invalid value, as ``"field=value: reason"`` strings (empty when valid)."""
        out = []
        if self.model not in SENSING_MODELS:
            out.append(f"{prefix}.model={self.model!r}: must be one of {SENSING_MODELS}")
        if not (_finite(self.period_s) and self.period_s > 0):
            out.append(f"{prefix}.period_s={self.period_s!r}: must be > 0")
        if not (_finite(self.latency_s) and self.latency_s >= 0):
            out.append(f"{prefix}.latency_s={self.latency_s!r}: must be >= 0")
        for f in dataclasses.fields(MeasurementNoise):
            value = getattr(self, f.name)
            if not (_finite(value) and value >= 0):
                out.append(f"{prefix}.{f.name}={value!r}: must be a standard deviation >= 0")
        bias = list(self.bias)
        if len(bias) != NX or not all(_finite(b) for b in bias):
            out.append(f"{prefix}.bias={bias!r}: must be {NX} finite numbers {STATE_NAMES}")
        return out


def _finite(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


class StateSensorModel:
    """Turns true states into measurements (``SensingConfig``; deterministic in ``seed``)."""

    def __init__(self, config: SensingConfig, seed: int = 0) -> None:
        problems = config.problems()
        if problems:
            raise ValueError("StateSensorModel: " + "; ".join(problems))
        self.config = config
        self.seed = int(seed)
        self._sigma = config.noise.sigma if config.enabled else np.zeros(NX)
        self._bias = np.asarray(config.bias, dtype=float) if config.enabled else np.zeros(NX)
        self._noisy = bool(np.any(self._sigma))
        self._normals = SeededNormals(self.seed, SENSING_STREAM)

    @property
    def sigma(self) -> np.ndarray:
        """Noise standard deviations in state order (zeros for ``model="none"``)."""
        return self._sigma.copy()

    def sample_index(self, t_s: float) -> int:
        """Index of the sensor sample that holds at time ``t_s``."""
        return int(math.floor(t_s / self.config.period_s + 1e-9))

    def noise(self, k: int) -> np.ndarray:
        """The noise of sample ``k`` (7,)."""
        if not self._noisy:
            return np.zeros(NX)
        if self._normals.seed != self.seed:
            self._normals = SeededNormals(self.seed, SENSING_STREAM)
        # default_rng([seed, SENSING_STREAM, k]).standard_normal(NX), drawn without building
        # the generator anew for each sample (pcvfe_drake.vehicle.seed_streams)
        return self._normals.normals(max(int(k), 0), NX) * self._sigma

    def measure(self, x_delayed: np.ndarray, t_s: float) -> np.ndarray:
        """The measurement at ``t_s`` of the (already delayed) true state ``x_delayed``."""
        x = np.asarray(x_delayed, dtype=float).reshape(NX)
        return x + self._bias + self.noise(self.sample_index(t_s))
