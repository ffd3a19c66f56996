"""The UKF baseline: filterpy's UKF with the batched process model, and mu as a random walk."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, MerweScaledSigmaPoints

from pcvfe_drake.estimation.ukf import MU, FrictionUkf, UkfConfig, _BatchedUkf
from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.vehicle.measurement_noise import MeasurementNoise
from pcvfe_drake.vehicle.params import ford_escort


def test_batched_ukf_equals_the_kalman_filter_on_a_linear_system():
    """Known linear case: a constant-velocity model with position measurements. The UKF is
    exact for linear models, so it must match filterpy's linear Kalman filter to rounding."""
    dt = 0.1
    F = np.array([[1.0, dt], [0.0, 1.0]])
    H = np.array([[1.0, 0.0]])
    Q = np.diag([1e-3, 1e-2])
    R = np.array([[0.04]])

    def fx(sigmas, dt_, **_):
        return np.atleast_2d(sigmas) @ F.T  # one call for every sigma point

    ukf = _BatchedUkf(
        dim_x=2,
        dim_z=1,
        dt=dt,
        hx=lambda x: H @ x,
        fx=fx,
        points=MerweScaledSigmaPoints(2, 0.1, 2.0, 1.0),
    )
    kf = KalmanFilter(dim_x=2, dim_z=1)
    for f in (ukf, kf):
        f.x = np.array([0.0, 1.0]) if f is ukf else np.array([[0.0], [1.0]])
        f.P = np.eye(2)
        f.Q, f.R = Q, R
    kf.F, kf.H = F, H
    rng = np.random.default_rng(0)
    for k in range(50):
        z = np.array([0.5 * k * dt + rng.normal(0, 0.2)])
        ukf.predict()
        ukf.update(z)
        kf.predict()
        kf.update(z)
    np.testing.assert_allclose(ukf.x, kf.x.ravel(), atol=1e-9)
    np.testing.assert_allclose(ukf.P, kf.P, atol=1e-9)


@pytest.mark.parametrize("mu_true", [0.3, 0.8])
def test_converges_on_a_single_terrain_log(mu_true):
    params = ford_escort()
    noise = MeasurementNoise()
    t, S, U = s_curve_drive(params, [mu_true], duration_s=12.0, speed_mps=8.0)
    Z = noise.apply(S[0], np.random.default_rng(3))
    ukf = FrictionUkf(params, noise.sigma)
    x, P = ukf.initial(Z[0])
    assert x[MU] == pytest.approx(params.mu)  # starts at the nominal 1.05
    mus = []
    for k in range(1, len(t)):
        x, P = ukf.step(x, P, U[0, k - 1], Z[k])
        mus.append(x[MU])
    late = np.array(mus[-500:])  # the last 5 s
    assert abs(late.mean() - mu_true) < 0.06 * mu_true + 0.01, late.mean()
    assert np.sqrt(P[MU, MU]) < 0.1
    # the state estimate filters the noise: closer to the truth than the measurements
    assert np.abs(x[:7] - S[0, -1])[5] < 3 * noise.psi_dot_radps


def test_bad_measurements_are_skipped_and_settings_checked():
    params = ford_escort()
    ukf = FrictionUkf(params, MeasurementNoise().sigma)
    x0 = np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    x, P = ukf.initial(x0)
    x1, P1 = ukf.step(x, P, [0.0, 0.0], np.full(7, np.nan))
    assert np.all(np.isfinite(x1)) and np.trace(P1) > np.trace(P)  # predict only
    with pytest.raises(ValueError, match="mu_walk_std"):
        UkfConfig(mu_walk_std=0.0)
    with pytest.raises(ValueError, match="sigma"):
        FrictionUkf(params, [0.1] * 6)
