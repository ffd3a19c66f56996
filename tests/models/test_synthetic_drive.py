"""The synthetic S-curve drive: a friction per drive, or per sample (a planted strip)."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.models.synthetic_drive import s_curve_drive
from pcvfe_drake.vehicle.params import ford_escort
from pcvfe_drake.vehicle.single_track import V


def test_a_friction_per_sample_drives_a_strip_and_a_constant_one_the_same_drive():
    params = ford_escort()
    n = 301
    t, S, U = s_curve_drive(params, [0.3], duration_s=3.0, delta_amp_rad=0.15)
    t2, S2, U2 = s_curve_drive(params, np.full((1, n), 0.3), duration_s=3.0, delta_amp_rad=0.15)
    np.testing.assert_array_equal(S, S2)
    np.testing.assert_array_equal(U, U2)
    strip = np.full((1, n), 0.3)
    strip[0, 150:200] = 0.9
    _, S3, _ = s_curve_drive(params, strip, duration_s=3.0, delta_amp_rad=0.15)
    np.testing.assert_array_equal(S3[:, :151], S[:, :151])  # the same up to the strip
    assert np.abs(S3[0, 151:] - S[0, 151:]).max() > 1e-3  # and not after it
    assert np.all(S3[0, :, V] > 0)
    with pytest.raises(ValueError, match="301 columns"):
        s_curve_drive(params, np.full((1, 300), 0.3), duration_s=3.0)
