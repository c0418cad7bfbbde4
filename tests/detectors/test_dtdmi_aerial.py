"""DTDMI ``aerial`` preset: the block contrast cue, the max fusion, preset regions, backends."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi import equations as eq
from eaglemission.detectors.dtdmi.config import PRESETS, resolve
from eaglemission.detectors.dtdmi.maps import lab_features

from eaglemission import registry
from eaglemission.types import Frame


def _frame(img: np.ndarray, i: int = 0, fps: float = 10.0) -> Frame:
    return Frame(img, int(1e9 + i * 1e9 / fps), "wide", i)


def test_block_contrast_hand_computed():
    f = np.zeros((21, 21, 3), np.float32)
    f[9:12, 9:12, 1] = 9.0  # a 3 x 3 block of value 9 in one channel
    c = eq.block_contrast_cue(f, radius_px=1, surround=3.0)  # centre 3 x 3, surround 7 x 7
    assert c[10, 10] == pytest.approx(9.0 - 81.0 / 49.0, rel=1e-5)
    assert c[0, 0] == 0.0 and c[20, 5] == 0.0  # far from it: uniform
    assert eq.block_contrast_cue(np.full((15, 15, 3), 4.0, np.float32), 2, 3.0).max() == 0.0
    # single-channel features: the absolute difference
    g = np.zeros((21, 21), np.float32)
    g[10, 10] = 49.0
    assert eq.block_contrast_cue(g, 1, 3.0)[10, 10] == pytest.approx(49 / 9 - 1.0, rel=1e-5)


def test_fused_max():
    s = np.array([0.2, 0.9, 0.0])
    m = np.array([0.5, 0.1, 0.0])
    np.testing.assert_allclose(eq.fused_saliency_max(s, m, 2.0), [1.0, 0.9, 0.0])


def test_lab_features_scale_luminance_only():
    img = np.zeros((4, 4, 3), np.uint8)
    img[..., :] = (20, 200, 60)
    a = lab_features(img, 1.0)
    b = lab_features(img, 0.3)
    assert a[0, 0, 0] == pytest.approx(b[0, 0, 0] / 0.3, rel=1e-5)
    np.testing.assert_array_equal(a[..., 1:], b[..., 1:])
    assert 0 <= a[0, 0, 0] <= 100 and a[0, 0, 1] < 0  # green: negative a*


def test_presets_resolve_and_literal_keeps_t120():
    aerial = resolve(DTDMIConfig(preset="aerial"))
    assert aerial.fusion == "max" and aerial.block_weight > 0 and aerial.ego_motion == "homography"
    for name in ("literal", "default", "field"):
        assert resolve(DTDMIConfig(preset=name)).ego_motion == "none"
    for name in ("literal", "field"):  # Eq. (15) without the block and colour cues
        assert resolve(DTDMIConfig(preset=name)).block_weight == 0.0
        assert resolve(DTDMIConfig(preset=name)).colour_weight == 1.0
    default = resolve(DTDMIConfig())
    assert default.block_fusion == "add" and default.block_weight > 0
    assert resolve(DTDMIConfig(preset="aerial", ego_motion="none")).ego_motion == "none"
    lit = DTDMIConfig(preset="literal").regions
    assert lit.threshold == "fixed" and lit.fixed_threshold == 120
    assert DTDMIConfig(preset="field").regions.threshold == "fixed"
    a = DTDMIConfig(preset="aerial", regions={"min_area_px": 30}).regions
    assert a.threshold == "adaptive" and a.min_area_px == 30  # the preset's, with the key on top
    assert DTDMIConfig(preset="aerial", regions={"threshold": "fixed"}).regions.threshold == "fixed"
    assert set(PRESETS) == {"literal", "default", "field", "aerial"}


def test_aerial_static_finds_a_small_contrasted_object_and_nothing_on_flat_ground(rng):
    det = registry.load("detectors", "dtdmi", {"preset": "aerial", "use_dynamic": False})
    flat = np.clip(rng.randn(240, 320, 3) * 2 + 110, 0, 255).astype(np.uint8)
    assert det.detect(_frame(flat)).detections == ()
    img = flat.copy()
    img[100:110, 200:214] = (40, 50, 190)
    res = det.detect(_frame(img))
    assert res.best is not None
    u, v = res.best.center_px
    assert 198 <= u <= 216 and 98 <= v <= 112


def test_aerial_map_is_the_max_of_the_static_and_the_scaled_dynamic_map(rng):
    """Eq. (15) as ``max(S_s, gain x S_M)`` in the whole detector: the map equals the maximum of
    the static-only map and gain x the dynamic-only map (before the output scale), on a moving
    checkerboard over grey ground."""
    base = {"preset": "aerial", "ego_motion": "none", "blur_sigma_frac": 0.0}
    full = DTDMIDetector(DTDMIConfig(**base))
    static = DTDMIDetector(DTDMIConfig(**base, use_dynamic=False))
    dynamic = DTDMIDetector(DTDMIConfig(**base, use_static=False))
    sat = resolve(DTDMIConfig(**base)).saturation
    gain = resolve(DTDMIConfig(**base)).dynamic_gain

    def raw(m):  # invert the absolute output S / (S + sat)
        return sat * m.astype(np.float64) / (1.0 - m)

    yy, xx = np.mgrid[0:24, 0:24]
    patch = np.where(((yy // 2 + xx // 2) % 2)[..., None] == 0, 40, 200).astype(np.uint8)
    for i in range(4):
        img = np.clip(rng.randn(120, 160, 3) * 2 + 120, 0, 255).astype(np.uint8)
        img[40:64, 30 + 8 * i:54 + 8 * i] = patch
        f = _frame(img, i)
        m, s_, d_ = (det.detect(f).saliency for det in (full, static, dynamic))
        expected = np.maximum(raw(s_), gain * raw(d_))
        np.testing.assert_allclose(raw(m), expected, rtol=1e-3, atol=1e-4)
        if i >= 1:  # S_M responds to the moving box, and there only
            dyn = gain * raw(d_)
            v, u = np.unravel_index(np.argmax(dyn), dyn.shape)
            assert dyn.max() > 0.1 and 36 <= v <= 68 and 26 + 8 * i <= u <= 58 + 8 * i


def test_aerial_backends_agree(rng):
    frames = [np.clip(rng.randn(96, 128, 3) * 20 + 100, 0, 255).astype(np.uint8)
              for _ in range(3)]
    for f in frames:
        f[30:40, 50:62] = (30, 40, 210)
    maps = {}
    for backend in ("numba", "numpy"):
        det = DTDMIDetector(DTDMIConfig(preset="aerial", backend=backend, ego_motion="none"))
        maps[backend] = [det.detect(_frame(f, i)).saliency for i, f in enumerate(frames)]
    for a, b in zip(maps["numba"], maps["numpy"]):
        np.testing.assert_allclose(a, b, atol=1e-4)


# -- real footage (skipped without ../shared) ---------------------------------------------------
def _uav_frames(root, seq: str, n: int):
    import cv2
    from eaglemission.lab.bench.boxes import parse_boxes

    folder = root / seq
    files = sorted((folder / "frames").glob("*.jpg"))[:n]
    boxes = parse_boxes((folder / "boxes.txt").read_text())[:n]
    return [cv2.imread(str(f)) for f in files], boxes


def test_aerial_regions_on_a_real_uav_sequence(uav_tracking):
    """The red car on the empty road (UAV123 car16_2, 12 frames at the mission's downscale 2):
    the aerial preset's best detection is on the car in most frames; the previous mission
    detector (field, T = 120) reports nothing there."""
    from eaglemission.lab.bench.boxes import score_frame

    frames, boxes = _uav_frames(uav_tracking, "UAV123_10fps/car16_2", 12)
    aerial = registry.load("detectors", "dtdmi", {"preset": "aerial", "downscale": 2})
    field = registry.load("detectors", "dtdmi", {"preset": "field", "use_dynamic": False,
                                                  "downscale": 2})
    hits = field_dets = 0
    for i, (img, box) in enumerate(zip(frames, boxes)):
        s = score_frame(aerial.detect(_frame(img, i)), box)
        hits += s.best_on_target
        field_dets += len(field.detect(_frame(img, i)).detections)
    assert hits >= 9, hits
    assert field_dets <= 3


def test_regions_stay_silent_on_target_free_real_ground(aerial_ground):
    """Mown grass of Garfield Park (a 1280 x 960 window upsampled ~2.3x, ~32 mm per pixel; the
    mission's downscale 2): no region from the mission's detector (with the mission's example
    image of the target) nor from the default preset
    (adaptive threshold above its floor); the aerial preset, whose floor is tuned for detection
    on real footage, may fire on the grass, but with a small red box pasted on it its best
    detection is the box."""
    import cv2

    from eaglemission.config import load_config

    photo = cv2.imread(str(aerial_ground / "garfield_park" / "IMG_161122_163244_0002_RGB.jpg"))
    window = cv2.resize(photo[300:950, 100:967], (1280, 960), interpolation=cv2.INTER_CUBIC)
    from eaglemission.flight.assembly import build_detector, target_appearance

    cfg = load_config(check_plugins=False)  # the mission's detector as it flies: with its image
    mission = build_detector(cfg, "wide", target_appearance(cfg))
    default = registry.load("detectors", "dtdmi", {"downscale": 2})
    for i in range(3):
        shifted = np.ascontiguousarray(np.roll(window, 4 * i, axis=1))
        assert mission.detect(_frame(shifted, i)).detections == ()
        assert default.detect(_frame(shifted, i)).detections == ()
    with_box = window.copy()
    with_box[500:524, 700:740] = (30, 40, 210)
    aerial = registry.load("detectors", "dtdmi", {"preset": "aerial", "downscale": 2})
    res = aerial.detect(_frame(with_box, 0))
    assert res.best is not None
    u, v = res.best.center_px
    assert 690 <= u <= 750 and 490 <= v <= 534


def test_use_dynamic_false_leaves_out_the_dynamic_part(rng):
    """``use_dynamic: false``: the map is the static part alone; on (the default), the dynamic
    part responds to a moving box."""
    dets = {k: DTDMIDetector(DTDMIConfig(preset="aerial", ego_motion="none", use_dynamic=v))
            for k, v in (("off", False), ("on", True))}
    assert not dets["off"].engine.use_dynamic and dets["on"].engine.use_dynamic
    moved = False
    for i in range(3):  # a box moving over noise: the dynamic part responds to it
        img = np.clip(rng.randn(96, 128, 3) * 20 + 100, 0, 255).astype(np.uint8)
        img[40:52, 20 + 10 * i:36 + 10 * i] = (200, 200, 200)
        maps = {k: d.detect(_frame(img, i)).saliency for k, d in dets.items()}
        moved = moved or not np.allclose(maps["on"], maps["off"], atol=1e-4)
    assert moved
