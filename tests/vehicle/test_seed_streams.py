"""The fast seeded normal draws are ``default_rng([seed, stream, k])``'s, bit for bit."""

import numpy as np
import pytest

from pcvfe_drake.vehicle.seed_streams import SeededNormals, pcg64_state, seed_state_words
from pcvfe_drake.vehicle.sensing import SENSING_STREAM, SensingConfig, StateSensorModel


def bits(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, dtype=np.float64).view(np.uint64)


@pytest.mark.parametrize("seed", [0, 1, 123456, 2**32 - 1])
def test_state_words_and_pcg64_state_are_numpys(seed):
    rng = np.random.default_rng(seed)
    ks = np.concatenate([np.arange(40), rng.integers(0, 2**32, 200), [2**32 - 1]])
    words = seed_state_words([seed, SENSING_STREAM], ks)
    for k, w in zip(ks, words, strict=True):
        seq = np.random.SeedSequence([seed, SENSING_STREAM, int(k)])
        assert np.array_equal(w, seq.generate_state(4, np.uint64))
        assert pcg64_state(w) == np.random.PCG64(seq).state


@pytest.mark.parametrize("seed", [0, 7, 2**32 - 1, 2**32])
def test_normals_equal_default_rng_in_any_order_of_samples(seed):
    # Consecutive samples across block boundaries, jumps back and forth, and a seed or indices
    # NumPy spreads over two words (through default_rng itself).
    normals = SeededNormals(seed, SENSING_STREAM)
    order = [*range(0, 1100, 1), 3, 2**20, 2**20 - 1, 5, 2**32 - 1, 2**32, 2**40 + 3, 0]
    for k in order:
        want = np.random.default_rng([seed, SENSING_STREAM, k]).standard_normal(7)
        assert np.array_equal(bits(normals.normals(k, 7)), bits(want)), k
    assert np.array_equal(
        bits(normals.normals(9, 3)),
        bits(np.random.default_rng([seed, SENSING_STREAM, 9]).standard_normal(3)),
    )


def test_the_sensor_noise_is_the_documented_generators():
    model = StateSensorModel(SensingConfig(model="ins"), seed=11)
    sigma = model.sigma
    for k in [0, 1, 2, 513, 512, 40_000, 3]:
        want = np.random.default_rng([11, SENSING_STREAM, k]).standard_normal(7) * sigma
        assert np.array_equal(bits(model.noise(k)), bits(want))
    model.seed = 12  # a changed seed is followed
    want = np.random.default_rng([12, SENSING_STREAM, 4]).standard_normal(7) * sigma
    assert np.array_equal(bits(model.noise(4)), bits(want))
    assert not np.any(StateSensorModel(SensingConfig(model="none"), seed=1).noise(5))


def test_a_negative_seed_is_refused_as_numpy_refuses_it():
    with pytest.raises(ValueError):
        SeededNormals(-1, SENSING_STREAM).normals(0, 7)
