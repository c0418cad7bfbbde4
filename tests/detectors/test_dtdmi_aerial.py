"""DTDMI ``aerial`` preset: the block contrast cue, the max fusion, preset regions, backends."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi import equations as eq
from eaglemission.detectors.dtdmi.detector import PRESETS, lab_features, resolve

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
        assert resolve(DTDMIConfig(preset=name)).block_weight == 0.0
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


def test_aerial_finds_a_moving_object_of_the_ground_colour(rng):
    """A fine checkerboard whose mean is the ground's grey, moving: the block contrast cannot
    see it (the static map stays below the floor), the midbrain map (max fusion) finds it."""
    params = {"preset": "aerial", "ego_motion": "none"}
    det = registry.load("detectors", "dtdmi", params)
    static = registry.load("detectors", "dtdmi", {**params, "use_dynamic": False})
    yy, xx = np.mgrid[0:24, 0:24]
    patch = np.where(((yy // 2 + xx // 2) % 2)[..., None] == 0, 40, 200).astype(np.uint8)
    hits = 0
    for i in range(6):
        img = np.clip(rng.randn(240, 320, 3) * 2 + 120, 0, 255).astype(np.uint8)
        u = 60 + 8 * i
        img[120:144, u:u + 24] = patch
        res = det.detect(_frame(img, i))
        assert static.detect(_frame(img, i)).detections == ()
        if i >= 1 and res.best is not None:
            cu, cv_ = res.best.center_px
            hits += (u - 6 <= cu <= u + 30) and (114 <= cv_ <= 150)
    assert hits == 5


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
