"""DTDMIDetector: state, time in seconds, robustness, scene-level behaviour."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from dtdmi_scenes import frame, moving_scene, texture
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi.dynamic import DynamicParams, MidbrainDynamic

from eaglemission import registry
from eaglemission.errors import InputError
from eaglemission.types import Frame


def _grey(img):
    return img.mean(axis=2).astype(np.float32) / 255.0


@pytest.mark.parametrize("name", ["dtdmi", "cluster_static", "midbrain"])
def test_plugins_register_and_return_unit_maps(name):
    rng = np.random.RandomState(3)
    cls = registry.get("detectors", name)
    det = cls(None, clock=object(), unused_context=1)  # context keys it does not use: ignored
    for f, _ in moving_scene(rng, n=3):
        res = det.detect(f)
        assert res.saliency.dtype == np.float32 and res.saliency.shape == f.image.shape[:2]
        assert 0.0 <= res.saliency.min() and res.saliency.max() <= 1.0


def test_static_scene_without_camera_motion_gives_near_zero_dynamic_map():
    rng = np.random.RandomState(11)
    img = texture(rng, 64, 80)
    dyn = MidbrainDynamic(DynamicParams(scales=(1.0, 0.5), tau_s=0.1))
    moving = texture(rng, 64, 80)
    peaks = []
    for i in range(8):
        maps = dyn.step(_grey(img), int(1e9 + i * 1e9 / 30))
        peaks.append(max(float(m.max()) for m in maps))
    # ...while a change of the scene does respond: "near zero" is relative to that.
    maps = dyn.step(_grey(moving), int(1e9 + 8 * 1e9 / 30))
    moving_peak = max(float(m.max()) for m in maps)
    assert moving_peak > 0
    assert max(peaks) <= 1e-6 * moving_peak


# Eq. (15) as a product, S = S_s^0.5 x S_M, without the block cue;
# a static scene or the first frame after a reset gives exactly 0 there.
PRODUCT = {"block_weight": 0.0, "colour_weight": 1.0, "blur_sigma_frac": 0.02,
           "centre_sigma_frac": 0.25, "colour_propagation": 0.0}


def test_dtdmi_static_scene_detects_nothing():
    rng = np.random.RandomState(12)
    img = texture(rng, 64, 80)
    det = DTDMIDetector(DTDMIConfig(**PRODUCT))
    plain = DTDMIDetector()  # the default (S_M + the block cue): some map, no region
    for i in range(6):
        assert plain.detect(frame(img, i)).detections == ()
    for i in range(6):
        res = det.detect(frame(img, i))
    assert res.saliency.max() == 0.0
    assert res.detections == ()


@pytest.mark.parametrize("ego", ["phase", "homography"])
def test_moving_target_over_moving_textured_background_is_found(ego):
    rng = np.random.RandomState(5)
    scene = moving_scene(rng, n=12, cam_px=(2, 1), target_px=(-2, 2))
    det = DTDMIDetector(DTDMIConfig(ego_motion=ego))
    hits = 0
    for f, (u, v) in scene:
        res = det.detect(f)
        if f.seq < 3:
            continue
        peak_v, peak_u = np.unravel_index(np.argmax(res.saliency), res.saliency.shape)
        hits += int(np.hypot(peak_u - u, peak_v - v) < 12)
    assert hits >= 7, f"target found in {hits}/9 frames"


def test_reset_and_fresh_detector_agree():
    rng = np.random.RandomState(7)
    scene = moving_scene(rng, n=5)
    det = DTDMIDetector()
    for f, _ in scene:
        det.detect(f)
    det.reset()
    fresh = DTDMIDetector()
    for f, _ in scene[:3]:
        a = det.detect(f).saliency
        b = fresh.detect(f).saliency
    np.testing.assert_array_equal(a, b)


def test_resolution_change_mid_stream_resets_state():
    rng = np.random.RandomState(8)
    det = DTDMIDetector(DTDMIConfig(**PRODUCT))
    for f, _ in moving_scene(rng, n=4, h=64, w=80):
        det.detect(f)
    small = moving_scene(rng, n=3, h=48, w=64)
    res = det.detect(Frame(small[0][0].image, int(5e9), "wide", 10))
    assert res.saliency.shape == (48, 64)
    assert res.saliency.max() == 0.0  # first frame after the reset: G_d = 0, no motion yet
    res = det.detect(Frame(small[1][0].image, int(5.04e9), "wide", 11))
    assert res.saliency.max() > 0.0


def test_dropped_frames_do_not_change_the_delay_state():
    rng = np.random.RandomState(9)
    a, b = texture(rng, 48, 64), texture(rng, 48, 64)
    full = MidbrainDynamic(DynamicParams(scales=(1.0,), tau_s=0.1, backend="numpy"))
    half = MidbrainDynamic(DynamicParams(scales=(1.0,), tau_s=0.1, backend="numpy"))
    # Scene a for 1 s, then b; "half" misses every other frame (gaps in the timestamps).
    for i in range(60):
        img = _grey(a if i < 30 else b)
        t = int(1e9 + i * 1e9 / 30)
        m_full = full.step(img, t)[0].copy()
        if i % 2 == 0:
            m_half = half.step(img, t)[0].copy()
        if i in (30, 34, 40):
            assert i % 2 == 0
            np.testing.assert_allclose(half._scales[0].g_delayed, full._scales[0].g_delayed,
                                       rtol=1e-4, atol=1e-6)
            np.testing.assert_allclose(m_half, m_full, rtol=1e-3, atol=1e-6 * m_full.max())
    assert m_full.max() >= 0


def test_non_increasing_timestamp_resets_with_warning(caplog):
    rng = np.random.RandomState(10)
    scene = moving_scene(rng, n=3)
    det = DTDMIDetector(DTDMIConfig(**PRODUCT))
    for f, _ in scene:
        det.detect(f)
    with caplog.at_level(logging.WARNING):
        res = det.detect(Frame(scene[1][0].image, scene[1][0].timestamp_ns, "wide", 9))
    assert "not after the previous" in caplog.text
    assert res.saliency.max() == 0.0


def test_bad_images_raise_clear_errors():
    from eaglemission.detectors.base import validate_image

    det = DTDMIDetector()
    with pytest.raises(InputError, match="at least 8x8"):
        det.detect(Frame(np.zeros((4, 32, 3), np.uint8), 1, "w", 0))
    # dtype and channel count: refused by Frame and by the detectors' validation
    for bad in (np.zeros((32, 32, 3), np.float32), np.zeros((32, 32, 4), np.uint8)):
        with pytest.raises(ValueError):
            Frame(bad, 1, "w", 0)
        with pytest.raises(InputError):
            validate_image(bad)


def test_grey_input_is_accepted():
    rng = np.random.RandomState(13)
    det = DTDMIDetector()
    for f, _ in moving_scene(rng, n=3):
        res = det.detect(Frame(np.ascontiguousarray(f.image[:, :, 1]), f.timestamp_ns, "w", f.seq))
    assert res.saliency.shape == f.image.shape[:2] and res.saliency.max() > 0


def test_downscale_keeps_frame_resolution():
    rng = np.random.RandomState(14)
    det = DTDMIDetector(DTDMIConfig(downscale=2))
    for f, _ in moving_scene(rng, n=3):
        res = det.detect(f)
    assert res.saliency.shape == f.image.shape[:2] and res.saliency.max() > 0


def test_config_rejects_bad_values():
    with pytest.raises(ValueError):
        DTDMIConfig(scales=(1.0, 1.5))
    with pytest.raises(ValueError):
        DTDMIConfig(tau_s=0)
    with pytest.raises(ValueError):
        DTDMIConfig(preset="paper")
