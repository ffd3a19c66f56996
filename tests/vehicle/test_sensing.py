"""The state sensing model: seeded noise per sample, bias, latency in samples."""

import numpy as np
import pytest

from pcvfe_drake.vehicle.sensing import SensingConfig, StateSensorModel

X = np.array([1.0, 2.0, 0.01, 5.0, 0.3, 0.1, 0.02])


def test_none_is_the_truth():
    model = StateSensorModel(SensingConfig(model="none"), seed=3)
    np.testing.assert_array_equal(model.measure(X, 1.234), X)


def test_ins_noise_has_the_configured_statistics_and_is_a_function_of_seed_and_sample():
    cfg = SensingConfig(model="ins", bias=[0.0, 0.0, 0.001, 0.0, 0.0, 0.0, 0.0])
    model = StateSensorModel(cfg, seed=5)
    y = np.array([model.measure(X, k * 0.01) for k in range(4000)]) - X
    assert np.all(np.abs(y.mean(axis=0) - cfg.bias) < 4 * cfg.noise.sigma / np.sqrt(4000))
    np.testing.assert_allclose(y.std(axis=0), cfg.noise.sigma, rtol=0.05)
    # held over a sample, new at the next one, same for the same seed, different for another
    np.testing.assert_array_equal(model.measure(X, 0.010), model.measure(X, 0.0149))
    assert not np.array_equal(model.measure(X, 0.010), model.measure(X, 0.020))
    np.testing.assert_array_equal(
        StateSensorModel(cfg, seed=5).measure(X, 0.5), model.measure(X, 0.5)
    )
    assert not np.array_equal(StateSensorModel(cfg, seed=6).measure(X, 0.5), model.measure(X, 0.5))


def test_latency_in_samples_and_invalid_settings():
    assert SensingConfig(model="ins", latency_s=0.024).latency_steps == 2
    with pytest.raises(ValueError, match=r"sensing.model='gps'"):
        StateSensorModel(SensingConfig(model="gps"))
    problems = SensingConfig(period_s=0.0, psi_rad=-1.0, bias=[0.0]).problems()
    assert any("period_s" in p for p in problems)
    assert any("psi_rad" in p for p in problems)
    assert any("bias" in p for p in problems)
