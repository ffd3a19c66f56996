"""The lookup-table baseline: nearest labelled prototype, rejection, mu table."""

import numpy as np
import pytest

from pcvfe_drake.estimation.lookup import (
    UNKNOWN_CLASS,
    build_lookup_table,
    render_texture_frames,
    table_from_features,
)
from pcvfe_drake.perception.camera import CameraConfig
from pcvfe_drake.perception.features import make_extractor
from pcvfe_drake.perception.texture_library import default_textures

CAMERA = CameraConfig(exposure_s=0.002, exposure_jitter=0.05, noise_std=3.0)


@pytest.fixture(scope="module")
def table_and_extractor():
    extractor = make_extractor("descriptor")
    classes = ["brick", "sand", "concrete", "gravel", "dry_soil", "snow"]
    table = build_lookup_table(extractor, classes, camera_config=CAMERA, frames_per_class=30)
    return table, extractor


def test_held_out_frames_of_known_textures_get_their_class_and_mu(table_and_extractor):
    table, extractor = table_and_extractor
    textures = default_textures()
    rng = np.random.default_rng(12345)  # frames never seen when the table was built
    for name in ("brick", "sand", "concrete"):
        z = extractor.extract(render_texture_frames(name, 10, rng, CAMERA, textures))
        labels = [table.classify(zi)[0] for zi in z]
        assert np.mean([table.classes[k] == name for k in labels if k >= 0]) == 1.0
        assert labels.count(UNKNOWN_CLASS) <= 1
        assert table.mu_for(z[0]) == textures.entry(name).mu


def test_unknown_textures_fall_back_to_the_default(table_and_extractor):
    table, extractor = table_and_extractor
    rng = np.random.default_rng(7)
    assert table.default_mu == 0.2  # the lowest mu in the table (snow)
    for name in ("patchy_grass", "leaves"):
        z = extractor.extract(render_texture_frames(name, 10, rng, CAMERA))
        assert all(table.classify(zi)[0] == UNKNOWN_CLASS for zi in z), name
        assert table.mu_for(z[0]) == 0.2
    assert table.classify(np.full(table.dim, np.nan))[0] == UNKNOWN_CLASS


def test_table_from_features_checks_its_input():
    z = {"a": np.array([[0.0, 0.0], [0.1, 0.0]]), "b": np.array([[1.0, 1.0], [1.1, 1.0]])}
    table = table_from_features(z, {"a": 0.3, "b": 0.7}, default_mu=0.5)
    assert table.mu_for([0.05, 0.0]) == 0.3 and table.mu_for([1.05, 1.0]) == 0.7
    assert table.mu_for([5.0, 5.0]) == 0.5
    with pytest.raises(ValueError, match="no mu"):
        table_from_features(z, {"a": 0.3})
    with pytest.raises(ValueError, match="not textures"):
        build_lookup_table(make_extractor("descriptor"), ["tarmac"])
