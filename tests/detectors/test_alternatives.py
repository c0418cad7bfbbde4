"""Alternative detectors (sr, ft, mss, motion_wang, centre_prior): contract and behaviour."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from eaglemission.detectors.centre_prior import centre_gaussian
from eaglemission.detectors.frequency_tuned import (
    frequency_tuned_distance,
    frequency_tuned_map,
    lab_float,
)
from eaglemission.detectors.mss import symmetric_surround_mean

from eaglemission import registry
from eaglemission.types import Frame

NAMES = ["sr", "ft", "mss", "motion_wang", "centre_prior"]


def _frame(img: np.ndarray, i: int = 0) -> Frame:
    return Frame(np.ascontiguousarray(img), 1_000_000_000 + i * 40_000_000, "wide", i)


def _scene(rng: np.random.RandomState, h: int = 120, w: int = 160) -> tuple[np.ndarray, tuple]:
    """Grey-green noisy ground with one bright yellow square; returns image and square box."""
    img = np.empty((h, w, 3), np.uint8)
    img[:] = (90, 110, 100)
    img = np.clip(img + rng.randn(h, w, 3) * 4, 0, 255).astype(np.uint8)
    box = (70, 40, 20, 16)  # u, v, width, height
    u, v, bw, bh = box
    img[v:v + bh, u:u + bw] = (40, 200, 240)
    return img, box


@pytest.mark.parametrize("name", NAMES)
def test_contract_float32_01_at_frame_resolution(name, rng):
    det = registry.load("detectors", name)
    for shape in [(77, 101, 3), (77, 101), (64, 48, 3)]:  # odd, grey, resolution change
        img = (rng.rand(*shape) * 255).astype(np.uint8)
        res = det.detect(_frame(img))
        assert res.saliency.dtype == np.float32
        assert res.saliency.shape == shape[:2]
        assert np.isfinite(res.saliency).all()
        assert res.saliency.min() >= 0.0 and res.saliency.max() <= 1.0
    det.reset()


@pytest.mark.parametrize("name", ["sr", "ft", "mss"])
def test_static_detectors_find_a_colour_square(name, rng):
    img, (u, v, bw, bh) = _scene(rng)
    res = registry.load("detectors", name).detect(_frame(img))
    best = res.best
    assert best is not None
    cu, cv_ = best.center_px
    tol = 10 if name == "sr" else 2  # SR (64 x 64 thumbnail) lights the square's edges
    assert abs(cu - (u + (bw - 1) / 2)) < tol and abs(cv_ - (v + (bh - 1) / 2)) < tol
    inside = res.saliency[v:v + bh, u:u + bw].mean()
    assert inside > 3 * res.saliency.mean()


@pytest.mark.parametrize("name", ["sr", "ft", "mss"])
def test_downscale_keeps_frame_resolution(name, rng):
    img, (u, v, bw, bh) = _scene(rng)
    res = registry.load("detectors", name, {"downscale": 2}).detect(_frame(img))
    assert res.saliency.shape == img.shape[:2]
    assert res.saliency[v:v + bh, u:u + bw].mean() > 2 * res.saliency.mean()


def test_ft_and_mss_stay_dark_on_an_even_scene(rng):
    """Absolute (fixed) scale: nothing salient -> no detection, unlike a min-max map."""
    img = np.clip(np.full((96, 128, 3), 120.0) + rng.randn(96, 128, 3) * 3, 0, 255).astype(np.uint8)
    for name in ("ft", "mss"):
        assert registry.load("detectors", name).detect(_frame(img)).detections == ()
        mm = registry.load("detectors", name, {"normalization": "minmax"}).detect(_frame(img))
        assert mm.saliency.max() == pytest.approx(1.0)


def test_ft_equals_brute_force(rng):
    img = (rng.rand(12, 15, 3) * 255).astype(np.uint8)
    lab = lab_float(img)
    d = frequency_tuned_distance(lab, 0.0)
    mean = lab.reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(d, np.linalg.norm(lab - mean, axis=2), rtol=1e-4, atol=1e-3)
    # Lab conversion: white is L=100, a=b=0
    np.testing.assert_allclose(lab_float(np.full((1, 1, 3), 255, np.uint8))[0, 0], [100, 0, 0],
                               atol=0.05)
    # fast path (8-bit blur) equals the reference within the 8-bit rounding
    big = cv2.resize(img, (60, 48), interpolation=cv2.INTER_CUBIC)
    fast = frequency_tuned_map(big, 1.0)
    slow = frequency_tuned_distance(lab_float(big), 1.0)
    assert np.abs(fast - slow).max() < 1.0 and np.abs(fast - slow).mean() < 0.3
    # 8-bit path within its quantisation of OpenCV's float conversion
    ref = cv2.cvtColor(img.astype(np.float32) / 255, cv2.COLOR_BGR2Lab)
    np.testing.assert_allclose(lab, ref, atol=3.0)
    assert np.abs(lab - ref).mean() < 0.6


@pytest.mark.parametrize("shape", [(9, 14), (10, 15), (1, 1), (2, 3), (1, 6)])
def test_symmetric_surround_mean_equals_brute_force(rng, shape):
    a = rng.rand(*shape, 3).astype(np.float32)
    out = symmetric_surround_mean(a)
    h, w = a.shape[:2]
    for y in range(h):
        for x in range(w):
            x0, y0 = min(x, w - 1 - x), min(y, h - 1 - y)
            ref = a[y - y0:y + y0 + 1, x - x0:x + x0 + 1].reshape(-1, 3).mean(axis=0)
            np.testing.assert_allclose(out[y, x], ref, rtol=1e-5, atol=1e-6)
    # corner pixels are their own surround; the centre sees the whole image
    np.testing.assert_allclose(out[0, 0], a[0, 0], rtol=1e-6)
    np.testing.assert_allclose(symmetric_surround_mean(a[:, :, 0])[0, 0], a[0, 0, 0], rtol=1e-6)


def test_centre_prior_values():
    g = centre_gaussian(101, 201)
    assert g[50, 100] == pytest.approx(1.0)
    assert g[50, 100 + round(0.25 * 201)] == pytest.approx(np.exp(-0.5 * (50 / 50.25) ** 2), rel=1e-6)
    assert g[50 + 25, 100] == pytest.approx(np.exp(-0.5 * (25 / 25.25) ** 2), rel=1e-6)
    det = registry.load("detectors", "centre_prior")
    res = det.detect(_frame(np.zeros((101, 201, 3), np.uint8)))
    np.testing.assert_array_equal(res.saliency, g)
    assert len(res.detections) == 1 and res.best.center_px == pytest.approx((100, 50), abs=0.6)


def test_motion_wang_learns_then_finds_a_moving_square(rng):
    det = registry.load("detectors", "motion_wang")
    bg = cv2.GaussianBlur((rng.rand(120, 160) * 255).astype(np.uint8), (0, 0), 3)
    found = []
    for i in range(75):
        g = bg.astype(np.float64) + rng.randn(120, 160) * 2
        u = 10 + 2 * i
        g[50:70, u:u + 20] = 250
        res = det.detect(_frame(np.clip(g, 0, 255).astype(np.uint8), i))
        if i < 10:
            assert not res.saliency.any()  # learning phase reported as empty
        if i >= 65:
            found.append(res.saliency[50:70, u:u + 20].mean() > 0.5 and res.saliency.mean() < 0.3)
    assert all(found)
    # resolution change: model rebuilt, learning again
    res = det.detect(_frame(np.zeros((60, 80), np.uint8), 100))
    assert res.saliency.shape == (60, 80) and not res.saliency.any()


def test_bad_params_rejected():
    from eaglemission.errors import ConfigError

    with pytest.raises(ConfigError, match="downscale"):
        registry.load("detectors", "ft", {"downscale": 0})
    with pytest.raises(ConfigError, match="unknown key"):
        registry.load("detectors", "sr", {"no_such_param": 1})


def _ground(rng: np.random.RandomState, h: int, w: int) -> np.ndarray:
    """Target-free ground: luminance value noise (3 octaves, std ~ 20 grey levels) with weak
    chroma noise around a vegetation green (natural textures vary mostly in brightness)."""
    def octaves(channels: int, amps: tuple[float, float, float]) -> np.ndarray:
        acc = np.zeros((h, w, channels), np.float32)
        for cell, amp in zip((32, 8, 2), amps):
            small = rng.randn(h // cell + 2, w // cell + 2, channels).astype(np.float32)
            acc += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC).reshape(h, w, channels)
        return acc
    img = octaves(1, (16.0, 10.0, 6.0)) + octaves(3, (4.0, 2.0, 1.0))
    return np.clip(img + np.array([50, 95, 70], np.float32), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("name", ["ft", "mss"])
def test_no_target_on_textured_ground_but_box_found(name, rng):
    tex = _ground(rng, 200, 300)
    det = registry.load("detectors", name)
    n_false = 0
    for i in range(8):
        img = tex[4 * i:4 * i + 120, 6 * i:6 * i + 160]
        n_false += len(det.detect(_frame(img, i)).detections)
    assert n_false == 0
    det.reset()
    tex[100:112, 120:140] = (30, 40, 210)  # the SITL config's red box, world-fixed
    for i in range(8):
        img = tex[4 * i:4 * i + 120, 6 * i:6 * i + 160]
        best = det.detect(_frame(img, i)).best
        assert best is not None
        assert np.hypot(best.center_px[0] - (129.5 - 6 * i), best.center_px[1] - (105.5 - 4 * i)) < 3
