"""Synthetic drives with a planted friction truth, for testing and benchmarking the fitter.

``s_curve_drive`` drives the ST model (``pcvfe_drake.vehicle.single_track.rk4_step``) through an
S-curve
course: sinusoidal steering (the steering angle follows ``delta_amp * sin(2 pi f t)``, commanded
as a steering rate) at a cruise speed held by a proportional speed controller with a small
sinusoidal speed variation. Several drives (e.g. one per terrain) are simulated as one batch.

The measurement noise is :class:`pcvfe_drake.vehicle.measurement_noise.MeasurementNoise`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import DELTA, NX, PSI, STATE_NAMES, V, rk4_step


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
        mu: friction coefficient(s): scalar, (D,) one per drive, or (D, N) one per drive and
            sample (the friction under the car from that sample to the next: a strip of another
            terrain planted in a drive).
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
    mu = np.asarray(mu, dtype=float)
    n = int(round(duration_s / dt)) + 1
    if mu.ndim == 2 and mu.shape[1] != n:
        raise ValueError(f"s_curve_drive: mu per sample needs {n} columns, got {mu.shape[1]}")
    mu_of = mu if mu.ndim == 2 else np.repeat(np.atleast_1d(mu)[:, None], n, axis=1)
    n_drives = mu_of.shape[0]
    phase = np.broadcast_to(np.asarray(phase_rad, dtype=float), (n_drives,))
    t = np.arange(n) * dt
    theta = np.stack(
        [mu_of[:, 0], np.full(n_drives, params.C_Sf), np.full(n_drives, params.C_Sr)], axis=1
    )
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
            theta[:, 0] = mu_of[:, i]
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
