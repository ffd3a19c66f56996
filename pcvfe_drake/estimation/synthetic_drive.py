"""Synthetic drives with a planted friction truth, for testing and benchmarking the fitter.

``s_curve_drive`` drives the ST model (``pcvfe_drake.vehicle.single_track.rk4_step``) through an
S-curve
course: sinusoidal steering (the steering angle follows ``delta_amp * sin(2 pi f t)``, commanded
as a steering rate) at a cruise speed held by a proportional speed controller with a small
sinusoidal speed variation. Several drives (e.g. one per terrain) are simulated as one batch.

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
import pandas as pd

from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import DELTA, NX, PSI, STATE_NAMES, V, rk4_step


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


def s_curve_drive(
    params: VehicleParams,
    mu,
    *,
    duration_s: float = 20.0,
    dt: float = 0.01,
    speed_mps: float = 8.0,
    delta_amp_rad: float = 0.1,
    steer_freq_hz: float = 0.3,
    phase_rad=0.0,
    hold_steps: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate S-curve drives of the ST model with friction ``mu`` (one drive per entry).

    Args:
        params: the vehicle (its stiffnesses are used; mu is replaced per drive).
        mu: friction coefficient(s), scalar or (D,).
        duration_s: length of each drive [s].
        dt: sample and integration step [s] (RK4).
        speed_mps: cruise speed [m/s].
        delta_amp_rad: steering angle amplitude [rad].
        steer_freq_hz: steering frequency [Hz].
        phase_rad: steering phase per drive [rad], scalar or (D,).
        hold_steps: the inputs are recomputed every ``hold_steps`` samples and held in between
            (e.g. 10 with dt = 0.01 s: a 10 Hz controller, so that every 10th sample is an
            exact 10 Hz log).
    Returns:
        ``(t (N,), states (D, N, 7), inputs (D, N, 2))`` with N = duration_s / dt + 1 samples;
        ``inputs[:, i]`` is held from ``t[i]`` to ``t[i+1]`` (the last row repeats the one before).
    """
    mu = np.atleast_1d(np.asarray(mu, dtype=float))
    n_drives = mu.shape[0]
    phase = np.broadcast_to(np.asarray(phase_rad, dtype=float), (n_drives,))
    n = int(round(duration_s / dt)) + 1
    t = np.arange(n) * dt
    theta = np.stack([mu, np.full(n_drives, params.C_Sf), np.full(n_drives, params.C_Sr)], axis=1)
    omega = 2.0 * np.pi * steer_freq_hz
    states = np.zeros((n_drives, n, NX))
    inputs = np.zeros((n_drives, n, 2))
    x = np.zeros((n_drives, NX))
    x[:, DELTA] = delta_amp_rad * np.sin(phase)
    x[:, V] = speed_mps
    x[:, PSI] = 0.0
    if int(hold_steps) != hold_steps or hold_steps < 1:
        raise ValueError(f"hold_steps must be an integer >= 1, got {hold_steps!r}")
    hold = dt * hold_steps
    u = np.zeros((n_drives, 2))
    for i in range(n):
        states[:, i] = x
        tk = t[i]
        if i % hold_steps == 0:
            # Steering rate that makes delta follow the sinusoid exactly over the hold.
            delta_next = delta_amp_rad * np.sin(omega * (tk + hold) + phase)
            steer_rate = (delta_next - x[:, DELTA]) / hold
            v_ref = speed_mps * (1.0 + 0.05 * np.sin(0.5 * omega * (tk + hold)))
            accel = np.clip(2.0 * (v_ref - x[:, V]), -3.0, 3.0)
            u = np.stack([steer_rate, accel], axis=1)
        inputs[:, i] = u
        if i + 1 < n:
            x = rk4_step(x, u, params, dt, theta=theta)
    return t, states, inputs


def drive_frame(
    t: np.ndarray, states: np.ndarray, inputs: np.ndarray, **extra_columns
) -> pd.DataFrame:
    """A drive-log table (``pcvfe_drake.runs.drivelog`` columns) from arrays of one drive."""
    data = {"t": np.asarray(t, dtype=float)}
    for j, name in enumerate(STATE_NAMES):
        data[name] = states[:, j]
    data["steer_rate"] = inputs[:, 0]
    data["accel"] = inputs[:, 1]
    data.update(extra_columns)
    return pd.DataFrame(data)
