"""Measurement noise of the project's sensors.

``MeasurementNoise`` is the one measurement-noise model of the project (the fitter's tests and
benchmarks, and the workbench's synthetic logs): independent zero-mean Gaussian noise on every
measured state, inputs noise-free (they are the recorded commands). Two documented levels:

=========  =========================  ===============================  =========================
state      ``MeasurementNoise()``      ``SURVEY_INS_NOISE``             typical source
           (fitter tests, benchmarks)  (workbench synthetic logs)
=========  =========================  ===============================  =========================
sx, sy     0.02 m                     0.02 m                           RTK GNSS position
delta      0.002 rad (0.11 deg)       0.001 rad                        steering angle encoder
v          0.05 m/s                   0.015 m/s                        GNSS/wheel-speed fusion
psi        0.5 deg (0.0087 rad)       0.002 rad                        dual-antenna GNSS heading
psi_dot    0.01 rad/s                 0.002 rad/s                      MEMS / tactical gyro
beta       0.005 rad (0.29 deg)       0.003 rad                        optical/GNSS slip sensor
=========  =========================  ===============================  =========================

The default is a GNSS/INS with RTK-grade position; ``SURVEY_INS_NOISE`` a survey-grade
dual-antenna RTK INS with a steering encoder, which the workbench assumes so that the model
discrepancies it ranks stand above the noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MeasurementNoise:
    """Standard deviations of independent Gaussian measurement noise per state (SI units)."""

    sx_m: float = 0.02
    sy_m: float = 0.02
    delta_rad: float = 0.002
    v_mps: float = 0.05
    psi_rad: float = float(np.deg2rad(0.5))
    psi_dot_radps: float = 0.01
    beta_rad: float = 0.005

    @property
    def sigma(self) -> np.ndarray:
        """Standard deviations in state order [sx, sy, delta, v, psi, psi_dot, beta]."""
        return np.array(
            [
                self.sx_m,
                self.sy_m,
                self.delta_rad,
                self.v_mps,
                self.psi_rad,
                self.psi_dot_radps,
                self.beta_rad,
            ]
        )

    def apply(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``states`` (..., 7) plus noise drawn from ``rng``."""
        states = np.asarray(states, dtype=float)
        return states + rng.standard_normal(states.shape) * self.sigma


SURVEY_INS_NOISE = MeasurementNoise(
    sx_m=0.02,
    sy_m=0.02,
    delta_rad=0.001,
    v_mps=0.015,
    psi_rad=0.002,
    psi_dot_radps=0.002,
    beta_rad=0.003,
)
"""Survey-grade GNSS/INS (dual-antenna RTK INS) and steering encoder: the workbench's synthetic
logs (``pcvfe_drake.workbench.synth``)."""
