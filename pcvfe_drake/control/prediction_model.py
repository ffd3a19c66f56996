"""Prediction models of the NMPC and their exact zero-order-hold discretisation.

* :func:`ks_jacobians`: the kinematic single-track model on the 7-entry ST state (the KMPC
  baseline's prediction model); the ST model's Jacobians are ``vehicle.single_track.st_jacobians``.
* :func:`discretize`: exact discretisation of the linearised dynamics over one controller step,
  from one batched matrix exponential of the augmented matrix ``[[A, B, f], [0, 0, 0]] dt``
  (:func:`expm_batched`; its speed against SciPy is measured in ``docs/nmpc.md``).

Pydrake-free; used by :class:`pcvfe_drake.control.nmpc.NmpcController`.
"""

from __future__ import annotations

import math

import numpy as np

from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import (
    BETA,
    DELTA,
    NU,
    NX,
    PSI,
    PSI_DOT,
    SX,
    SY,
    V,
    constrain_inputs,
)


def ks_jacobians(x: np.ndarray, u: np.ndarray, params: VehicleParams, relax_s: float):
    """Kinematic single-track model on the 7-entry ST state, batched: ``(f, A, B)``.

    sx' = v cos(psi + beta_k), sy' = v sin(psi + beta_k), delta' = steer, v' = accel,
    psi' = v cos(beta_k) tan(delta) / L, with beta_k = atan(lr tan(delta) / L); the states
    psi_dot and beta relax to psi'_k and beta_k with time constant ``relax_s`` [s]. Inputs pass
    through CommonRoad's constraints (``vehicle.constrain_inputs``).
    """
    n = x.shape[0]
    wb = params.L
    u_eff, d_steer, d_acc_du1, d_acc_dv = constrain_inputs(x, u, params)
    delta, v, psi, r, beta = x[:, DELTA], x[:, V], x[:, PSI], x[:, PSI_DOT], x[:, BETA]
    c = params.lr / wb
    t = np.tan(delta)
    sec2 = 1.0 + t * t
    q = 1.0 + c * c * t * t
    beta_k = np.arctan(c * t)
    dbeta_k = c * sec2 / q
    gk = t / np.sqrt(q)
    dgk = q**-1.5 * sec2
    yaw_k = v * gk / wb
    cs, sn = np.cos(psi + beta_k), np.sin(psi + beta_k)
    inv = 1.0 / relax_s
    f = np.empty((n, NX))
    f[:, SX] = v * cs
    f[:, SY] = v * sn
    f[:, DELTA] = u_eff[:, 0]
    f[:, V] = u_eff[:, 1]
    f[:, PSI] = yaw_k
    f[:, PSI_DOT] = (yaw_k - r) * inv
    f[:, BETA] = (beta_k - beta) * inv
    A = np.zeros((n, NX, NX))
    B = np.zeros((n, NX, NU))
    A[:, SX, V] = cs
    A[:, SY, V] = sn
    A[:, SX, PSI] = -v * sn
    A[:, SY, PSI] = v * cs
    A[:, SX, DELTA] = -v * sn * dbeta_k
    A[:, SY, DELTA] = v * cs * dbeta_k
    A[:, V, V] = d_acc_dv
    A[:, PSI, V] = gk / wb
    A[:, PSI, DELTA] = v * dgk / wb
    A[:, PSI_DOT, V] = gk / wb * inv
    A[:, PSI_DOT, DELTA] = v * dgk / wb * inv
    A[:, PSI_DOT, PSI_DOT] = -inv
    A[:, BETA, DELTA] = dbeta_k * inv
    A[:, BETA, BETA] = -inv
    B[:, DELTA, 0] = d_steer
    B[:, V, 1] = d_acc_du1
    return f, A, B


def expm_batched(m: np.ndarray) -> np.ndarray:
    """Matrix exponentials of a batch of square matrices (B, n, n).

    Scaling and squaring with a degree-12 Taylor polynomial (Horner form): the batch is scaled
    by 2^-s so that every 1-norm is <= 0.5 (truncation error below 2e-14 relative), then squared
    s times. Vectorised over the batch (scipy's expm loops over it in Python).
    """
    norm = float(np.abs(m).sum(axis=-2).max()) if m.size else 0.0
    s = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    a = m / 2.0**s
    eye = np.eye(m.shape[-1])
    e = eye + a / 12.0
    for k in range(11, 0, -1):
        e = eye + (a @ e) / k
    for _ in range(s):
        e = e @ e
    return e


def discretize(f: np.ndarray, A: np.ndarray, B: np.ndarray, dt: float):
    """Exact zero-order-hold discretisation of ``dx' = A dx + B du + f`` over ``dt``, batched.

    Returns ``(Ad, Bd, g)`` with ``dx(dt) = Ad dx(0) + Bd du + g`` (shapes (N,7,7), (N,7,2),
    (N,7)), from one batched matrix exponential of ``[[A, B, f], [0, 0, 0]] dt``.
    """
    n = f.shape[0]
    m = np.zeros((n, NX + NU + 1, NX + NU + 1))
    m[:, :NX, :NX] = A * dt
    m[:, :NX, NX : NX + NU] = B * dt
    m[:, :NX, -1] = f * dt
    e = expm_batched(m)
    return e[:, :NX, :NX], e[:, :NX, NX : NX + NU], e[:, :NX, -1]
