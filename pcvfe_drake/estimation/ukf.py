"""The buffer-based baseline: an unscented Kalman filter, mu a random-walk state (no pydrake).

The paper compares PC-VFE with "a buffer-based method akin to a UKF": one estimator for the
whole drive, no contexts, no vision. :class:`FrictionUkf` is that baseline, built on filterpy's
``UnscentedKalmanFilter`` (Merwe scaled sigma points):

* state ``[sx, sy, delta, v, psi, psi_dot, beta, mu]`` (the ST state and mu), process model one
  RK4 step of the single-track model (``pcvfe_drake.vehicle.single_track.rk4_step``) with theta =
  [mu, C_Sf, C_Sr] (nominal stiffnesses) and the applied input held; mu follows a random walk
  (``mu_walk_std`` per sqrt(s)), clipped to ``mu_bounds`` inside the model;
* measurement the measured ST state (7), noise ``R = diag(sigma^2)`` from the sensing model
  (floored at ``min_sigma`` so a noise-free measurement stays well conditioned);
* process noise ``Q = diag(q^2) dt`` with ``q`` the model-error densities per state
  (``process_std``, per sqrt(s)).

The sigma points are propagated as one batch (the ST model is vectorised): filterpy's loop over
sigma points is replaced by one call (:class:`_BatchedUkf`), 17 states per RK4 step. The
filter's (x, P) travel in and out of :meth:`FrictionUkf.step`, so the LeafSystem keeps them as
discrete state and the filterpy object is only a workspace.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import NU, NX, rk4_step

MU = NX
"""Index of mu in the filter state."""
NXA = NX + 1
"""Length of the filter state (ST state and mu)."""


@dataclass
class UkfConfig:
    """Tuning of the friction UKF (SI units; densities per sqrt(s)).

    The scenario's ``ukf:`` section (``estimator: ukf``); lists, not tuples, so that a scenario
    file can set them. Checked at construction (``dataclasses.replace`` checks again).

    Attributes:
        period_s: filter step [s] (one predict + update per measurement).
        mu0: initial mu (None: the vehicle's nominal mu).
        mu0_std: initial standard deviation of mu.
        mu_walk_std: random-walk density of mu [1/sqrt(s)]: how fast mu may change (a terrain
            step of 0.3 is followed within a few seconds of cornering).
        process_std: model-error densities of the 7 ST states [unit/sqrt(s)].
        min_sigma: floor on the measurement standard deviations (state order).
        mu_bounds: [lo, hi], mu is clipped to this range (model and estimate).
        alpha, beta, kappa: Merwe sigma-point parameters (0 < alpha <= 1, beta >= 0, and
            n + kappa > 0 for the filter's n = 8 states).
    """

    period_s: float = 0.01
    mu0: float | None = None
    mu0_std: float = 0.3
    mu_walk_std: float = 0.05
    process_std: list[float] = field(
        default_factory=lambda: [0.05, 0.05, 0.005, 0.2, 0.01, 0.1, 0.02]
    )
    min_sigma: list[float] = field(
        default_factory=lambda: [1e-3, 1e-3, 1e-4, 1e-3, 1e-4, 1e-3, 1e-4]
    )
    mu_bounds: list[float] = field(default_factory=lambda: [0.05, 2.0])
    alpha: float = 0.1
    beta: float = 2.0
    kappa: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.period_s) and self.period_s > 0):
            raise ValueError(f"UkfConfig.period_s={self.period_s!r} must be > 0")
        for name in ("mu0_std", "mu_walk_std"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"UkfConfig.{name}={value!r} must be > 0")
        for name in ("process_std", "min_sigma"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (NX,) or not np.all(np.isfinite(value)) or np.any(value <= 0):
                raise ValueError(
                    f"UkfConfig.{name} must be {NX} numbers > 0, got {getattr(self, name)!r}"
                )
        bounds = np.asarray(self.mu_bounds, dtype=float)
        if bounds.shape != (2,) or not (0 < bounds[0] < bounds[1] < math.inf):
            raise ValueError(
                f"UkfConfig.mu_bounds={self.mu_bounds!r} must be [lo, hi] with 0 < lo < hi"
            )
        if self.mu0 is not None and not (bounds[0] <= self.mu0 <= bounds[1]):
            raise ValueError(
                f"UkfConfig.mu0={self.mu0!r} must be None or within mu_bounds {self.mu_bounds!r}"
            )
        if not (math.isfinite(self.alpha) and 0 < self.alpha <= 1):
            raise ValueError(f"UkfConfig.alpha={self.alpha!r} must be in (0, 1]")
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise ValueError(f"UkfConfig.beta={self.beta!r} must be >= 0")
        if not (math.isfinite(self.kappa) and NXA + self.kappa > 0):
            raise ValueError(f"UkfConfig.kappa={self.kappa!r} must be > -{NXA} (n + kappa > 0)")


class _BatchedUkf(UnscentedKalmanFilter):
    """filterpy's UKF with the sigma points propagated in one vectorised call of ``fx``."""

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        fx = self.fx if fx is None else fx
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = fx(sigmas, dt, **fx_args)


class FrictionUkf:
    """The friction UKF of the module docstring for one vehicle.

    Args:
        params: the vehicle (model, nominal stiffnesses, nominal mu).
        sigma: measurement noise standard deviations of the 7 ST states.
        config: tuning (default ``UkfConfig()``).
    """

    def __init__(self, params: VehicleParams, sigma, config: UkfConfig | None = None) -> None:
        self.params = params
        self.config = config if config is not None else UkfConfig()
        sigma = np.asarray(sigma, dtype=float).reshape(-1)
        if sigma.shape != (NX,) or not np.all(np.isfinite(sigma)) or np.any(sigma < 0):
            raise ValueError(f"FrictionUkf: sigma must be {NX} numbers >= 0, got {sigma!r}")
        cfg = self.config
        self.R = np.diag(np.maximum(sigma, np.asarray(cfg.min_sigma)) ** 2)
        q = np.append(np.asarray(cfg.process_std, dtype=float), cfg.mu_walk_std)
        self.Q = np.diag(q**2 * cfg.period_s)
        points = MerweScaledSigmaPoints(NXA, alpha=cfg.alpha, beta=cfg.beta, kappa=cfg.kappa)
        self._ukf = _BatchedUkf(
            dim_x=NXA, dim_z=NX, dt=cfg.period_s, hx=self._hx, fx=self._fx, points=points
        )
        self._ukf.Q = self.Q
        self._ukf.R = self.R
        self._stiffness = np.array([params.C_Sf, params.C_Sr])

    @property
    def mu0(self) -> float:
        return self.params.mu if self.config.mu0 is None else float(self.config.mu0)

    def initial(self, x_measured) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) to start from a first measured state (7,)."""
        x = np.append(np.asarray(x_measured, dtype=float).reshape(NX), self.mu0)
        p = np.diag(np.append(np.diag(self.R) * 4.0, self.config.mu0_std**2))
        return x, p

    def _fx(self, sigmas: np.ndarray, dt: float, u: np.ndarray) -> np.ndarray:
        sig = np.atleast_2d(sigmas)
        lo, hi = self.config.mu_bounds
        mu = np.clip(sig[:, MU], lo, hi)
        theta = np.column_stack([mu, np.broadcast_to(self._stiffness, (len(mu), 2))])
        out = np.empty_like(sig)
        out[:, :NX] = rk4_step(sig[:, :NX], u, self.params, dt, theta=theta)
        out[:, MU] = mu
        return out

    @staticmethod
    def _hx(x: np.ndarray) -> np.ndarray:
        return x[:NX]

    def step(self, x, p, u, z) -> tuple[np.ndarray, np.ndarray]:
        """One predict (input ``u`` (2,) held over ``period_s``) and update with the measured
        state ``z`` (7,); returns the new (x, P). A non-finite measurement skips the update; a
        covariance that is no longer positive definite restarts from ``initial(z)`` with the
        current mu."""
        ukf = self._ukf
        ukf.x = np.array(x, dtype=float)
        ukf.P = np.array(p, dtype=float)
        u = np.asarray(u, dtype=float).reshape(NU)
        z = np.asarray(z, dtype=float).reshape(NX)
        try:
            ukf.predict(u=np.nan_to_num(u))
            if np.all(np.isfinite(z)):
                ukf.update(z)
        except np.linalg.LinAlgError:
            return self._restart(x, z)
        x_new = np.array(ukf.x, dtype=float)
        p_new = 0.5 * (ukf.P + ukf.P.T)
        if not (np.all(np.isfinite(x_new)) and np.all(np.isfinite(p_new))):
            return self._restart(x, z)
        lo, hi = self.config.mu_bounds
        x_new[MU] = float(np.clip(x_new[MU], lo, hi))
        return x_new, p_new

    def _restart(self, x, z) -> tuple[np.ndarray, np.ndarray]:
        mu = float(np.asarray(x, dtype=float)[MU]) if np.isfinite(x[MU]) else self.mu0
        base = z if np.all(np.isfinite(z)) else np.asarray(x, dtype=float)[:NX]
        x0, p0 = self.initial(base)
        x0[MU] = mu
        return x0, p0
