"""Geometry of the plan and friction-circle layers: speed colours, accelerations, utilisation.

Accelerations are in the vehicle frame [m/s^2]: ``a_x`` longitudinal (the acceleration input of
the single-track model), ``a_y = v * psi_dot`` lateral (the centripetal acceleration of the
single-track model at small slip). State order: ``pcvfe_drake.vehicle.single_track``.
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.vehicle.single_track import NU, NX, PSI_DOT, V

G_MPS2 = 9.81

# Slow to fast: blue, cyan, green, yellow, red.
SPEED_RGB = np.array(
    [
        [0.19, 0.31, 0.85],
        [0.10, 0.75, 0.85],
        [0.20, 0.75, 0.25],
        [0.95, 0.80, 0.10],
        [0.90, 0.15, 0.10],
    ]
)


def speed_bins(v_mps: np.ndarray, v_max_mps: float, n_bins: int = len(SPEED_RGB)) -> np.ndarray:
    """Colour bin (0 slowest .. n_bins-1 fastest) of each speed on a linear scale 0..v_max_mps.

    Non-finite speeds get bin 0; speeds beyond ``v_max_mps`` the last bin.
    """
    if not (np.isfinite(v_max_mps) and v_max_mps > 0):
        raise ValueError(f"v_max_mps must be a positive speed, got {v_max_mps!r}")
    v = np.nan_to_num(np.asarray(v_mps, dtype=float), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip((v / v_max_mps * n_bins).astype(int), 0, n_bins - 1)


def speed_bin_edges(v_max_mps: float, n_bins: int = len(SPEED_RGB)) -> np.ndarray:
    """(n_bins + 1,) speed bin edges [m/s] (the legend of the plan's colours)."""
    return np.linspace(0.0, v_max_mps, n_bins + 1)


def actual_acceleration(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``(a_x, a_y)`` [m/s^2] of the measured state ``x`` (7,) under the applied input ``u``."""
    x = np.asarray(x, dtype=float).reshape(NX)
    u = np.asarray(u, dtype=float).reshape(NU)
    return np.array([u[1], x[V] * x[PSI_DOT]])


def planned_accelerations(x_pred: np.ndarray, u_pred: np.ndarray) -> np.ndarray:
    """(N, 2) planned ``(a_x, a_y)`` [m/s^2] at the stages 0..N-1 of a predicted trajectory."""
    x_pred = np.asarray(x_pred, dtype=float).reshape(-1, NX)
    u_pred = np.asarray(u_pred, dtype=float).reshape(-1, NU)
    n = len(u_pred)
    if len(x_pred) < n:
        raise ValueError(f"x_pred has {len(x_pred)} states, need at least {n} for {n} inputs")
    return np.column_stack([u_pred[:, 1], x_pred[:n, V] * x_pred[:n, PSI_DOT]])


def utilisation(a_xy: np.ndarray, mu: float, g_mps2: float = G_MPS2) -> np.ndarray:
    """Friction utilisation ``|a| / (mu g)`` of accelerations (..., 2); > 1 exceeds the circle.

    A non-finite or non-positive ``mu`` gives nan (no circle to compare with).
    """
    a = np.asarray(a_xy, dtype=float)
    norm = np.hypot(a[..., 0], a[..., 1])
    if not (np.isfinite(mu) and mu > 0):
        return np.full(norm.shape, np.nan)
    return norm / (mu * g_mps2)


def unit_circle(n: int = 64) -> np.ndarray:
    """(n + 1, 2) closed polyline of the unit circle."""
    a = np.linspace(0.0, 2.0 * np.pi, n + 1)
    return np.column_stack([np.cos(a), np.sin(a)])


def stride_indices(n: int, stride: int) -> np.ndarray:
    """Indices 0, stride, 2 stride, ... of ``n`` points, always including the last one."""
    if n <= 0:
        return np.zeros(0, dtype=int)
    stride = max(1, int(stride))
    idx = np.arange(0, n, stride)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return idx
