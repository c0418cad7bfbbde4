"""The fused numba kernels equal the plain numpy equations within 1e-5 (small images)."""

from __future__ import annotations

import numpy as np
import pytest
from dtdmi_scenes import moving_scene
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi.kernels import midbrain_step_fused
from eaglemission.detectors.dtdmi.midbrain_step import midbrain_step_numpy


@pytest.mark.parametrize("radius", [0, 1, 2, 5])
def test_fused_step_equals_numpy_reference(radius):
    rng = np.random.RandomState(21)
    h, w = 23, 37  # odd sizes: borders on every side
    gd_a = np.zeros((h, w), np.float32)
    gp_a = np.zeros((h, w), np.float32)
    gd_b, gp_b = gd_a.copy(), gp_a.copy()
    o = np.zeros((h, w), np.float32)
    sm_b = np.zeros((h, w), np.float32)
    for i, gain in enumerate([0.0, 0.3, 0.5, 1.0]):
        grey = rng.rand(h, w).astype(np.float32)
        tau = np.inf if gain == 0 else 1.0 / gain
        sm_a, gd_a, gp_a = midbrain_step_numpy(grey, gd_a, gp_a, tau, radius, 1e-20)
        midbrain_step_fused(grey, gd_b, gp_b, gain, radius, o, sm_b, 1e-20)
        np.testing.assert_allclose(gd_b, gd_a, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(gp_b, gp_a, rtol=1e-5, atol=1e-7)
        scale = max(float(sm_a.max()), 1e-30)
        np.testing.assert_allclose(sm_b / scale, sm_a / scale, rtol=1e-5, atol=1e-5)
        if i > 0:
            assert sm_a.max() > 0


@pytest.mark.parametrize("preset", ["literal", "default"])
def test_detector_numba_and_numpy_backends_agree(preset):
    rng = np.random.RandomState(22)
    scene = moving_scene(rng, n=4, h=40, w=56, size=10)
    a = DTDMIDetector(DTDMIConfig(preset=preset, backend="numpy"))
    b = DTDMIDetector(DTDMIConfig(preset=preset, backend="numba"))
    for f, _ in scene:
        np.testing.assert_allclose(b.saliency(f), a.saliency(f), atol=1e-5)


def test_detector_backends_agree_with_pooled_smoothing():
    """At 320x240 the (pre-issue-14) default preset's smoothing reduces by 2, so the numba
    backend takes the fused Eq. (14)-(15) + block-mean path (``combine_pooled``) instead of a
    full plane."""
    rng = np.random.RandomState(23)
    scene = moving_scene(rng, n=4, h=240, w=320, size=24)
    product = {"preset": "default", "block_weight": 0.0, "colour_weight": 1.0,
               "blur_sigma_frac": 0.02, "centre_sigma_frac": 0.25}
    a = DTDMIDetector(DTDMIConfig(**product, backend="numpy"))
    b = DTDMIDetector(DTDMIConfig(**product, backend="numba"))
    for f, _ in scene:
        sb = b.saliency(f)
        assert b.engine._pool_f == 2
        assert b.engine._half is not None  # the full scale reads the 8-bit grey image
        np.testing.assert_allclose(sb, a.saliency(f), atol=1e-5)
    assert sb.max() > 1e-3  # a live map, not all zeros


@pytest.mark.parametrize(("scales", "on_the_fly"), [((1.0, 0.5, 0.25), True), ((1.0, 0.3), False)])
def test_backends_agree_with_coarse_scales_upsampled_on_the_fly_or_not(scales, on_the_fly):
    """The numba kernels upsample the coarse scales row by row where that equals OpenCV's
    bilinear resize (power-of-two factors), else they read an OpenCV-upsampled plane."""
    rng = np.random.RandomState(24)
    scene = moving_scene(rng, n=4, h=120, w=160, size=16)
    a = DTDMIDetector(DTDMIConfig(preset="literal", scales=scales, backend="numpy"))
    b = DTDMIDetector(DTDMIConfig(preset="literal", scales=scales, backend="numba"))
    for f, _ in scene:
        np.testing.assert_allclose(b.saliency(f), a.saliency(f), atol=1e-5)
    assert all(full is None for _, full in b.engine._up.cache.values()) == on_the_fly


@pytest.mark.parametrize("params", [
    {"normalize_scales": True},  # per-scale maxima first: not streamed
    {"scales": (0.5, 0.25)},  # no full-resolution scale
    {"scales": (1.0, 0.5, 0.25, 0.125)},  # three coarse scales: summed at the largest
    {"preset": "field"},  # Eq. (15) as a boost, in the streamed pass
    {"preset": "field", "centre_sigma_frac": 0.25},  # boost, then the centre weight: own pass
    {"preset": "literal", "ego_motion": "phase"},
    {"colour_propagation": 1.0},  # the map replaced by its colour means (kernels.blend_lut)
    {"preset": "aerial", "colour_propagation": 0.5},  # the general path, then the blend
])
def test_backends_agree_on_other_paths(params):
    rng = np.random.RandomState(25)
    scene = moving_scene(rng, n=4, h=64, w=96, size=12)
    a = DTDMIDetector(DTDMIConfig(**{**params, "backend": "numpy"}))
    b = DTDMIDetector(DTDMIConfig(**{**params, "backend": "numba"}))
    for f, _ in scene:
        np.testing.assert_allclose(b.saliency(f), a.saliency(f), atol=1e-5)


def test_quarter_scale_grey_from_the_half_scale_equals_area_reduction_of_the_frame():
    import cv2
    from eaglemission.detectors.dtdmi.dynamic import DynamicParams, MidbrainDynamic

    grey = np.random.RandomState(26).rand(96, 128).astype(np.float32)
    dyn = MidbrainDynamic(DynamicParams(scales=(1.0, 0.5, 0.25)))
    dyn.step(grey, 1_000_000_000, defer=True)
    quarter = dyn.deferred[2][1]
    ref = cv2.resize(grey, (32, 24), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(quarter, ref, rtol=0, atol=1e-6)
    assert [d[0].shape for d in dyn.deferred] == [(96, 128), (48, 64), (24, 32)]


@pytest.mark.parametrize(("h", "w", "eight_bit"), [(48, 64, True), (42, 54, False), (37, 53, False)])
def test_backends_agree_with_and_without_the_8bit_grey_path(h, w, eight_bit):
    """The 8-bit grey path needs every coarse scale exactly half the one before (42x54: the
    half scale 21x27 has no exact half; 37x53: odd)."""
    rng = np.random.RandomState(27)
    scene = moving_scene(rng, n=3, h=h, w=w, size=10)
    a = DTDMIDetector(DTDMIConfig(preset="literal", backend="numpy"))
    b = DTDMIDetector(DTDMIConfig(preset="literal", backend="numba"))
    for f, _ in scene:
        np.testing.assert_allclose(b.saliency(f), a.saliency(f), atol=1e-5)
    assert (b.engine._half is not None) == eight_bit
