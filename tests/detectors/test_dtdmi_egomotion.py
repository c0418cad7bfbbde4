"""Ego-motion estimation and the warping of the delay-unit state."""

from __future__ import annotations

import cv2
import numpy as np
from eaglemission.detectors.dtdmi import egomotion


def _texture(rng, h, w):
    t = cv2.GaussianBlur(rng.rand(h, w).astype(np.float32), (0, 0), 2.0)
    return (t - t.min()) / (t.max() - t.min())


def test_phase_correlation_gives_the_content_shift():
    rng = np.random.RandomState(31)
    big = _texture(rng, 300, 400)
    prev = big[50:250, 50:350].copy()
    cur = big[48:248, 47:347].copy()  # content moved +3 px right, +2 px down
    hm = egomotion.phase_motion(prev, cur, 1.0)
    np.testing.assert_allclose(hm[:2, 2], [3.0, 2.0], atol=0.3)
    # at scale 0.5 the same pixel shift means twice the full-resolution motion
    np.testing.assert_allclose(egomotion.phase_motion(prev, cur, 0.5)[:2, 2], [6.0, 4.0], atol=0.6)


def test_homography_recovers_a_perspective_motion():
    rng = np.random.RandomState(32)
    prev = _texture(rng, 240, 320)
    true = np.array([[1.01, 0.02, 4.0], [-0.01, 0.99, -3.0], [2e-5, 1e-5, 1.0]])
    cur = cv2.warpPerspective(prev, true, (320, 240), flags=cv2.INTER_LINEAR)
    hm = egomotion.homography_motion(prev, cur, 1.0)
    pts = np.array([[80.0, 60.0, 1.0], [240.0, 60.0, 1.0], [160.0, 180.0, 1.0]]).T
    a = true @ pts
    b = hm @ pts
    np.testing.assert_allclose(b[:2] / b[2], a[:2] / a[2], atol=0.5)


def test_unreliable_estimates_fall_back_to_identity():
    flat = np.full((60, 80), 0.5, np.float32)
    np.testing.assert_array_equal(egomotion.homography_motion(flat, flat, 1.0), np.eye(3))


def test_homography_at_scale_round_trip():
    hm = np.array([[1.0, 0.0, 8.0], [0.0, 1.0, -4.0], [0.0, 0.0, 1.0]])
    hs = egomotion.homography_at_scale(hm, 0.25)
    np.testing.assert_allclose(hs[:2, 2], [2.0, -1.0])


def test_integer_shift_warp_has_no_blur_and_zero_fill():
    plane = np.arange(20, dtype=np.float32).reshape(4, 5)
    out = np.empty_like(plane)
    hm = np.array([[1.0, 0.0, 2.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    egomotion.warp_state(plane, hm, out)
    np.testing.assert_array_equal(out[1:, 2:], plane[:-1, :-2])
    assert np.all(out[0] == 0) and np.all(out[:, :2] == 0)


def test_homography_on_a_low_contrast_texture_is_a_translation():
    # A blurred texture spanning only 40..160 grey levels: without the contrast stretch LK
    # tracking fails and RANSAC accepted a 10 % scale change for a pure 2 px shift.
    rng = np.random.RandomState(5)
    t = cv2.GaussianBlur(rng.rand(200, 250, 3).astype(np.float32), (0, 0), 1.5)
    t = (40 + 120 * (t - t.min()) / (t.max() - t.min())).astype(np.uint8)
    grey = t.mean(axis=2).astype(np.float32) / 255.0
    prev, cur = grey[20:116, 20:148], grey[21:117, 22:150]  # content moves (-2, -1)
    hm = egomotion.homography_motion(prev, cur, 1.0)
    np.testing.assert_allclose(hm[:2, :2], np.eye(2), atol=0.02)
    np.testing.assert_allclose(hm[:2, 2], [-2.0, -1.0], atol=0.25)


def test_compensation_cancels_a_translating_background():
    from eaglemission.detectors.dtdmi.dynamic import DynamicParams, MidbrainDynamic

    rng = np.random.RandomState(6)
    t = cv2.GaussianBlur(rng.rand(300, 300).astype(np.float32), (0, 0), 1.5)
    peaks = {}
    for ego in ("none", "phase", "homography"):
        d = MidbrainDynamic(DynamicParams(scales=(1.0,), ego_motion=ego))
        for i in range(6):
            m = d.step(np.ascontiguousarray(t[20 + i:116 + i, 20 + 2 * i:148 + 2 * i]),
                       int(1e9 + i * 1e9 / 30))[0]
        peaks[ego] = float(m[8:-8, 8:-8].max())  # interior: the uncovered border strip aside
    assert peaks["none"] > 0
    assert peaks["phase"] < 1e-2 * peaks["none"]
    assert peaks["homography"] < 1e-2 * peaks["none"]
