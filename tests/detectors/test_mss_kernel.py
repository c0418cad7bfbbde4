"""The fused (numba) MSS pass equals the numpy/OpenCV reference pass it replaced."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from eaglemission.detectors.frequency_tuned import scale_map
from eaglemission.detectors.mss import MaximumSymmetricSurroundDetector, mss_distance

from eaglemission.types import Frame


def _lab_pair(rng: np.random.RandomState, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    img = rng.randint(0, 256, (*shape, 3)).astype(np.uint8)
    if min(shape) >= 8:
        img = cv2.GaussianBlur(img, (0, 0), 2.0)
    lab8 = cv2.cvtColor(img, cv2.COLOR_BGR2Lab)
    blurred8 = cv2.GaussianBlur(lab8, (0, 0), 1.0) if min(shape) >= 3 else lab8
    return lab8, blurred8


@pytest.mark.parametrize("shape", [(1, 1), (1, 6), (7, 1), (2, 3), (9, 14), (10, 15), (48, 64),
                                   (121, 160)])
def test_kernel_equals_numpy_reference(shape):
    rng = np.random.RandomState(7)
    lab8, blurred8 = _lab_pair(rng, shape)
    ref = mss_distance(lab8, blurred8, backend="numpy")
    out = mss_distance(lab8, blurred8)
    assert out.dtype == np.float32 and out.shape == shape
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-4)  # Lab units (map full scale 120)


def test_fused_fixed_scale_equals_scale_map():
    rng = np.random.RandomState(8)
    lab8, blurred8 = _lab_pair(rng, (60, 80))
    ref = scale_map(mss_distance(lab8, blurred8, backend="numpy"), "fixed", 20.0)
    out = mss_distance(lab8, blurred8, full_scale_lab=20.0)
    assert out.max() == 1.0 and out.min() >= 0.0  # the scale clips somewhere in this image
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5)


def test_detector_output_unchanged_by_the_kernel(monkeypatch):
    """Saliency map and detections of the detector with the kernel vs the reference path."""
    rng = np.random.RandomState(9)
    img = np.full((240, 320, 3), (60, 120, 70), np.uint8)
    img = cv2.add(img, rng.randint(0, 20, img.shape).astype(np.uint8))
    cv2.rectangle(img, (150, 100), (175, 118), (30, 40, 210), -1)
    frame = Frame(img, 1, "wide", 1)
    det = MaximumSymmetricSurroundDetector(MaximumSymmetricSurroundDetector.Config(downscale=2))
    fast = det.detect(frame)
    import eaglemission.detectors.mss as mss

    orig = mss.mss_distance
    monkeypatch.setattr(mss, "mss_distance",
                        lambda a, b, **kw: orig(a, b, **{**kw, "backend": "numpy"}))
    slow = MaximumSymmetricSurroundDetector(
        MaximumSymmetricSurroundDetector.Config(downscale=2)).detect(frame)
    np.testing.assert_allclose(fast.saliency, slow.saliency, rtol=0, atol=1e-6)
    assert len(fast.detections) == len(slow.detections) >= 1
    for a, b in zip(fast.detections, slow.detections):
        np.testing.assert_allclose(a.corners_px, b.corners_px, atol=1e-9)
    c = fast.detections[0].center_px
    assert 150 <= c[0] <= 175 and 100 <= c[1] <= 118
