"""The general path's fused kernels (detectors/dtdmi/kernels_general.py) equal the plain
functions they replace, and the two backends agree on the paths that use them."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi.equations_static import block_contrast_cue
from eaglemission.detectors.dtdmi.maps import block_contrast_into, lab_features

from eaglemission.types import Frame


def _image(rng: np.random.RandomState, h: int, w: int) -> np.ndarray:
    img = np.clip(rng.randn(h, w, 3) * 30 + 110, 0, 255).astype(np.uint8)
    img[h // 3:h // 3 + max(2, h // 8), w // 2:w // 2 + max(2, w // 7)] = (30, 40, 210)
    return img


@pytest.mark.parametrize("h, w, radius, surround, lw", [
    (48, 64, 2, 3.0, 0.6),
    (37, 53, 1, 3.0, 0.3),    # odd sizes, the smallest blocks
    (20, 24, 4, 4.0, 1.0),    # surround (16 px) near the image size: reflected twice
    (120, 160, 4, 3.0, 0.0),  # chromatic only
    (10, 13, 3, 5.0, 0.6),    # surround (15 px) beyond the image: OpenCV's repeated reflection
])
def test_block_cue_kernel_equals_the_box_means(h, w, radius, surround, lw):
    img = _image(np.random.RandomState(h + w), h, w)
    expected = block_contrast_cue(lab_features(img, lw), radius, surround) * np.float32(0.05)
    out = np.full((h, w), -1.0, np.float32)
    block_contrast_into(img, lw, radius, surround, 0.05, out, accumulate=False)
    np.testing.assert_allclose(out, expected, rtol=1e-4, atol=1e-5)
    base = np.random.RandomState(1).rand(h, w).astype(np.float32)
    acc = base.copy()
    block_contrast_into(img, lw, radius, surround, 0.05, acc, accumulate=True)
    np.testing.assert_allclose(acc, base + expected, rtol=1e-4, atol=1e-5)
    assert out.max() > 0.1  # the red patch stands out


@pytest.mark.parametrize("params", [
    {"preset": "aerial", "use_dynamic": False},                  # the hardware template's
    {"preset": "aerial", "ego_motion": "none"},                  # with the dynamic part
    {"preset": "aerial", "use_dynamic": False, "block_fusion": "add", "colour_weight": 0.5},
    {"preset": "default"},                                       # block cue added after Eq. 15
])
def test_backends_agree(params):
    rng = np.random.RandomState(7)
    dets = {b: DTDMIDetector(DTDMIConfig(**{**params, "backend": b}))
            for b in ("numba", "numpy")}
    for i in range(4):
        img = _image(rng, 72, 96)
        img = np.roll(img, 3 * i, axis=1)
        frame = Frame(img, 1_000_000_000 + i * 100_000_000, "wide", i)
        a, b = (dets[k].detect(frame) for k in ("numpy", "numba"))
        np.testing.assert_allclose(b.saliency, a.saliency, atol=1e-5)
        np.testing.assert_allclose([d.center_px for d in b.detections],
                                   [d.center_px for d in a.detections], atol=1e-3)


def test_cv2_reflect_padding_is_the_box_filters_border():
    """The kernel pads once by the surround's half-size; a box filter of a smaller block reads
    the same reflected pixels (BORDER_REFLECT is position-wise)."""
    img = np.arange(7 * 9 * 3, dtype=np.uint8).reshape(7, 9, 3)
    padded = cv2.copyMakeBorder(img, 5, 5, 5, 5, cv2.BORDER_REFLECT)
    small = cv2.copyMakeBorder(img, 2, 2, 2, 2, cv2.BORDER_REFLECT)
    np.testing.assert_array_equal(padded[3:-3, 3:-3], small)


@pytest.mark.parametrize("fusion", ["static", "add"])
@pytest.mark.parametrize("fused", [True, False])
def test_block_cue_at_a_reduced_resolution(fusion, fused):
    """``block_downscale`` 2: the cue of the frame halved (area average, the radius from the
    halved diagonal), upsampled bilinearly; both backends, both fusions."""
    from dataclasses import replace

    from eaglemission.detectors.dtdmi.config import resolve
    from eaglemission.detectors.dtdmi.maps import add_block_cue

    r = replace(resolve(DTDMIConfig(preset="aerial")), block_fusion=fusion)
    assert r.block_downscale == 2
    img = _image(np.random.RandomState(5), 96, 128)
    half = cv2.resize(img, (64, 48), interpolation=cv2.INTER_AREA)
    radius = round(r.block_radius_frac * float(np.hypot(48, 64)))
    cue = block_contrast_cue(lab_features(half, r.block_luminance_weight), radius,
                             r.block_surround) * np.float32(r.block_weight / r.block_unit)
    expected = cv2.resize(cue, (128, 96), interpolation=cv2.INTER_LINEAR)
    base = np.random.RandomState(2).rand(96, 128).astype(np.float32)
    plane = np.zeros((96, 128), np.float32) if fused else None
    s, blk = add_block_cue(img, r, base.copy(), plane)
    if fusion == "static":
        assert blk is None
        np.testing.assert_allclose(s, base + expected, rtol=1e-4, atol=1e-5)
    else:
        np.testing.assert_allclose(s, base)
        np.testing.assert_allclose(blk, expected, rtol=1e-4, atol=1e-5)
