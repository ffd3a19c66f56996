"""``synth.simulate_truths``: a log keeps its noise when simulated in another batch."""

from __future__ import annotations

import pytest

from pcvfe_drake.workbench import synth


def test_noise_seeds_give_a_log_the_noise_of_its_own_batch():
    drag = synth.PLANTED["drag"][0]
    run = {"duration_s": 4.0, "rate_hz": 20.0, "seed": 0, "substeps": 2}
    clean, alone = synth.simulate_truths([synth.Truth(), drag], **run)
    lag = synth.PLANTED["steering_lag"][0]
    joined = synth.simulate_truths([lag, drag, synth.Truth()], noise_seeds=[9, 2, 1], **run)
    assert joined[1].equals(alone) and joined[2].equals(clean)
    # the noise seed matters: the default seed of index 1 is 2
    assert not synth.simulate_truths([drag, drag], **run)[0].equals(alone)


def test_noise_seeds_must_match_the_truths():
    with pytest.raises(ValueError, match="simulate_truths: 1 noise seeds for 2 truths"):
        synth.simulate_truths([synth.Truth(), synth.Truth()], duration_s=2.0, noise_seeds=[1])
