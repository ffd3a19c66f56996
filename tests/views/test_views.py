"""Geometry of the Meshcat debugging layers (plain numpy): speed colours, accelerations,
utilisation, PCA projection, text images, frame captions."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.control.plan import NmpcPlan
from pcvfe_drake.perception.features import DescriptorExtractor
from pcvfe_drake.views.feature_projection import PcaProjection, centroids
from pcvfe_drake.views.labels import FrameCaptioner, text_image, thumbnail
from pcvfe_drake.views.plan_geometry import (
    G_MPS2,
    actual_acceleration,
    planned_accelerations,
    speed_bin_edges,
    speed_bins,
    stride_indices,
    unit_circle,
    utilisation,
)


def test_speed_bins_span_the_scale():
    v = np.array([0.0, 2.9, 3.1, 14.9, 15.0, 40.0, np.nan])
    np.testing.assert_array_equal(speed_bins(v, 15.0), [0, 0, 1, 4, 4, 4, 0])
    np.testing.assert_allclose(speed_bin_edges(15.0), [0, 3, 6, 9, 12, 15])
    with pytest.raises(ValueError, match="v_max_mps"):
        speed_bins(v, 0.0)


def test_accelerations_and_utilisation():
    x = np.array([0, 0, 0.1, 10.0, 0, 0.3, 0.02])
    np.testing.assert_allclose(actual_acceleration(x, [0.2, -2.0]), [-2.0, 3.0])
    xs = np.tile(x, (4, 1))
    xs[:, 3] = [5, 10, 15, 20]
    us = np.column_stack([np.zeros(3), [1.0, 2.0, 3.0]])
    np.testing.assert_allclose(planned_accelerations(xs, us), [[1, 1.5], [2, 3.0], [3, 4.5]])
    a = np.array([[3.0, 4.0], [0.0, 0.0]])
    np.testing.assert_allclose(utilisation(a, 0.5), [5 / (0.5 * G_MPS2), 0.0])
    assert np.all(np.isnan(utilisation(a, float("nan"))))
    with pytest.raises(ValueError, match="x_pred"):
        planned_accelerations(xs[:2], us)


def test_circle_and_strides():
    c = unit_circle(8)
    np.testing.assert_allclose(np.hypot(c[:, 0], c[:, 1]), 1.0)
    np.testing.assert_allclose(c[0], c[-1], atol=1e-12)
    np.testing.assert_array_equal(stride_indices(41, 4), [0, 4, 8, 12, 16, 20, 24, 28, 32, 36, 40])
    np.testing.assert_array_equal(stride_indices(10, 4), [0, 4, 8, 9])
    assert stride_indices(0, 3).size == 0


def test_pca_recovers_the_planted_axes():
    rng = np.random.default_rng(1)
    # Variance 9, 4, 1 along three known directions of a 6-D space, nothing else.
    basis = np.linalg.qr(rng.standard_normal((6, 6)))[0][:, :3].T
    coeff = rng.standard_normal((400, 3)) * [3.0, 2.0, 1.0]
    z = 5.0 + coeff @ basis
    fit = PcaProjection.fit(z, size_m=10.0, origin_m=(1.0, 2.0, 3.0))
    for i in range(3):
        assert abs(fit.axes[i] @ basis[i]) == pytest.approx(1.0, abs=0.02)
    assert fit.explained.sum() == pytest.approx(1.0)
    p = fit.project(z)
    np.testing.assert_allclose(p.mean(axis=0), [1.0, 2.0, 3.0], atol=1e-9)
    assert np.max(np.abs(p - [1.0, 2.0, 3.0])) == pytest.approx(5.0)
    np.testing.assert_allclose(fit.project(z[0]), p[0])
    with pytest.raises(ValueError, match="dimension"):
        fit.project(np.zeros(5))
    with pytest.raises(ValueError, match="no finite"):
        PcaProjection.fit(np.full((3, 2), np.nan))
    cents = centroids(np.array([[0, 0, 0], [2, 0, 0], [5, 5, 5]]), np.array([1, 1, -1]))
    assert list(cents) == [1]
    np.testing.assert_allclose(cents[1], [1, 0, 0])


def test_text_and_thumbnail_images():
    image = text_image("context 3", height_px=40, rgb=(1, 0, 0), background=(0, 0, 0))
    assert image.shape[0] == 40 and image.dtype == np.uint8
    assert image[..., 0].max() > 200 and image[..., 1].max() < 60  # red text on black
    assert text_image("x" * 200).shape[1] < text_image("x" * 60).shape[1] * 1.1
    thumb = thumbnail(np.full((100, 80, 4), 7, np.uint8), 16)
    assert thumb.shape == (16, 16, 3) and np.all(thumb == 7)


def test_captioner_names_the_nearest_texture():
    extractor = DescriptorExtractor()
    rng = np.random.default_rng(0)
    smooth = np.full((96, 96, 3), 120, np.uint8)
    noisy = rng.integers(0, 255, (96, 96, 3), dtype=np.uint8)
    captioner = FrameCaptioner(extractor, {"smooth": smooth, "noisy": noisy})
    assert captioner(extractor.extract([noisy])[0]) == "nearest texture: noisy"
    assert captioner(extractor.extract([smooth + 3])[0]) == "nearest texture: smooth"
    assert captioner(np.full(extractor.dim, np.nan)) == ""


def test_plan_flags():
    assert not NmpcPlan().has_prediction and not NmpcPlan().is_fallback
    assert NmpcPlan(mode="braking").is_fallback
