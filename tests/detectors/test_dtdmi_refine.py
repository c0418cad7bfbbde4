"""DTDMI map refinements beyond the paper: colour propagation, following the previous best
detection, unpooled appearance bins (detectors/dtdmi/refine.py and their use)."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.detectors.appearance import AppearanceModel
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi.config import resolve
from eaglemission.detectors.dtdmi.engine import DTDMIEngine, propagate_by_colour
from eaglemission.detectors.dtdmi.refine import (
    colour_mean_saliency,
    propagated_saliency,
    spotlit_saliency,
)
from eaglemission.detectors.dtdmi.static import quantize_bgr

from eaglemission import registry
from eaglemission.types import Frame

RED = (30, 40, 210)
GREEN = (60, 140, 70)


def _frame(img: np.ndarray, i: int = 0, fps: float = 10.0) -> Frame:
    return Frame(img, int(1e9 + i * 1e9 / fps), "wide", i)


def test_colour_mean_saliency_hand_computed():
    lut = colour_mean_saliency([2, 0, 4], [1.0, 5.0, 2.0])
    assert lut.dtype == np.float32
    np.testing.assert_allclose(lut, [0.5, 0.0, 0.5])  # an empty bin gives 0, whatever its sum
    with pytest.raises(ValueError, match="same shape"):
        colour_mean_saliency([1, 2], [1.0])


def test_propagated_saliency_blends():
    s = np.array([[1.0, 0.0], [0.2, 0.4]], np.float32)
    p = np.array([[0.5, 0.5], [0.0, 1.0]], np.float32)
    np.testing.assert_array_equal(propagated_saliency(s, p, 0.0), s)
    np.testing.assert_array_equal(propagated_saliency(s, p, 1.0), p)
    np.testing.assert_allclose(propagated_saliency(s, p, 0.25), 0.75 * s + 0.25 * p, rtol=1e-6)
    with pytest.raises(ValueError, match="weight"):
        propagated_saliency(s, p, 1.5)
    with pytest.raises(ValueError, match="same shape"):
        propagated_saliency(s, p[:1], 0.5)


def test_spotlit_saliency_matches_the_formula(rng):
    sal = rng.rand(30, 40).astype(np.float32)
    out = spotlit_saliency(sal, (12.0, 20.0), 5.0, 0.4)
    v, u = np.mgrid[0:30, 0:40]
    g = np.exp(-((u - 12.0) ** 2 + (v - 20.0) ** 2) / (2 * 25.0))
    np.testing.assert_allclose(out, sal * (0.6 + 0.4 * g), rtol=1e-5)
    assert out[20, 12] == pytest.approx(sal[20, 12])  # unchanged at the centre
    assert out[0, 39] == pytest.approx(0.6 * sal[0, 39], rel=1e-4)  # far: (1 - a) x
    np.testing.assert_array_equal(spotlit_saliency(sal, (5.0, 5.0), 3.0, 0.0), sal)
    with pytest.raises(ValueError, match="strength"):
        spotlit_saliency(sal, (5.0, 5.0), 3.0, -0.1)
    with pytest.raises(ValueError, match="sigma"):
        spotlit_saliency(sal, (5.0, 5.0), 0.0, 0.5)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_colour_propagation_spreads_the_map_over_the_colour(backend):
    """Left half red, right half green; the map is 1 on the red top quarter only: the red bin's
    mean saliency is 0.5 (half of its pixels), the green's 0."""
    img = np.empty((40, 60, 3), np.uint8)
    img[:, :30] = RED
    img[:, 30:] = GREEN
    sal = np.zeros((40, 60), np.float32)
    sal[:20, :30] = 1.0
    eng = DTDMIEngine(DTDMIConfig(colour_propagation=0.5, backend=backend))
    eng.saliency(img, 1_000_000_000)  # allocates at this resolution
    out = propagate_by_colour(sal, img, 0.5, eng._k if eng.numba else None, eng._paint)
    assert out[5, 5] == pytest.approx(0.75)  # 0.5 x 1 + 0.5 x 0.5
    assert out[30, 5] == pytest.approx(0.25)  # 0.5 x 0 + 0.5 x 0.5: the rest of the red half
    assert out[:, 30:].max() == 0.0


def test_presets_keep_their_behaviour_unless_they_choose_a_refinement():
    for name in ("literal", "field"):
        r = resolve(DTDMIConfig(preset=name))
        assert r.colour_propagation == 0.0
        assert r.appearance_pool is True and r.appearance_track_weight == 0.0
        assert r.appearance_rank_exponent == 4.0
    r = resolve(DTDMIConfig(preset="field", colour_propagation=0.3, appearance_pool=False))
    assert r.colour_propagation == 0.3 and r.appearance_pool is False
    aerial = resolve(DTDMIConfig(preset="aerial"))
    assert aerial.appearance_pool is False and aerial.appearance_rank_exponent == 8.0
    assert aerial.colour_propagation == 0.0 and aerial.appearance_track_weight == 0.3
    assert aerial.appearance_floor == 30 and aerial.appearance_peak_fraction == 0.7
    assert aerial.appearance_exposure_span == 1.5
    assert resolve(DTDMIConfig()).colour_propagation == 0.5  # default: chosen on DAVIS
    assert resolve(DTDMIConfig(preset="aerial",
                               appearance_rank_exponent=0)).appearance_rank_exponent == 0


def test_colour_propagation_changes_the_map_only_when_asked(rng):
    img = rng.randint(0, 256, (48, 64, 3)).astype(np.uint8)
    img[10:20, 10:30] = RED
    maps = []
    for cp in (0.0, 0.5):
        det = DTDMIDetector(DTDMIConfig(colour_propagation=cp, centre_sigma_frac=0.0))
        for i in range(3):
            res = det.detect(_frame(img, i))
        maps.append(res.saliency)
    assert maps[0].max() > 0
    assert not np.allclose(maps[0], maps[1])
    assert 0.0 <= maps[1].min() and maps[1].max() <= 1.0


def test_unpooled_appearance_model_keeps_the_exact_bins():
    crop = np.zeros((12, 12, 3), np.uint8)
    crop[...] = RED
    crop[:, 6:] = (200, 90, 20)
    pooled = registry.load("detectors", "dtdmi", {"preset": "aerial", "appearance_pool": True,
                                                  "appearance_exposure_span": 1.0},
                           appearance=crop)
    exact = registry.load("detectors", "dtdmi", {"preset": "aerial",
                                                 "appearance_exposure_span": 1.0},
                          appearance=crop)
    assert pooled.engine.appearance.pool and not exact.engine.appearance.pool
    bins = set(np.unique(quantize_bgr(crop)).tolist())
    assert set(np.flatnonzero(exact.engine.appearance.q).tolist()) <= bins
    assert np.count_nonzero(pooled.engine.appearance.q) > 2 * len(bins)
    assert isinstance(exact.engine.appearance, AppearanceModel)


def _two_boxes(rng: np.random.RandomState, left: bool, right_size: int) -> np.ndarray:
    img = np.empty((120, 200, 3), np.float32)
    img[...] = GREEN
    img += rng.randn(120, 200, 3).astype(np.float32) * 4
    img = np.clip(img, 0, 255).astype(np.uint8)
    if left:
        img[50:60, 30:42] = RED
    img[50:50 + right_size, 150:150 + right_size + 2] = RED
    return img


def test_following_the_previous_best_detection_keeps_the_target(rng):
    """Frames 0-2: one red box (left) only; frame 3 adds a bigger red box (right). Without
    following, the bigger box wins frame 3; following the previous best keeps the left one."""
    crop = np.full((10, 12, 3), RED, np.uint8)
    frames = [_two_boxes(rng, True, 0) for _ in range(3)] + [_two_boxes(rng, True, 16)]
    best = {}
    for weight in (0.0, 0.6):
        det = registry.load("detectors", "dtdmi", {
            "preset": "aerial", "use_dynamic": False, "appearance_track_weight": weight},
            appearance=crop)
        for i, f in enumerate(frames):
            res = det.detect(_frame(f, i))
        assert res.best is not None
        best[weight] = res.best.center_px
        assert det.track_px == res.best.center_px
        det.reset()
        assert det.track_px is None
    assert best[0.0][0] > 140  # the bigger box on the right
    assert best[0.6][0] < 50  # the box it was following


def test_following_needs_a_previous_detection(rng):
    """The first frame after a reset (no previous detection) is not attenuated."""
    crop = np.full((10, 12, 3), RED, np.uint8)
    f = _two_boxes(rng, True, 16)
    on = registry.load("detectors", "dtdmi", {
        "preset": "aerial", "use_dynamic": False, "appearance_track_weight": 0.6},
        appearance=crop)
    off = registry.load("detectors", "dtdmi", {
        "preset": "aerial", "use_dynamic": False, "appearance_track_weight": 0.0},
        appearance=crop)
    np.testing.assert_array_equal(on.detect(_frame(f)).saliency, off.detect(_frame(f)).saliency)


@pytest.mark.parametrize(("params", "image", "fraction"), [
    ({"preset": "aerial"}, True, 0.7),       # the preset's, with an image
    ({"preset": "aerial", "regions": {"peak_fraction": 0.6}}, True, 0.7),  # the image's wins
    ({"preset": "aerial"}, False, 0.8),      # regions.peak_fraction without one
    ({"preset": "aerial", "appearance_peak_fraction": 0.9}, True, 0.9),
    ({"preset": "aerial", "regions": {"peak_fraction": 0.6}}, False, 0.6),
])
def test_the_adaptive_threshold_with_an_image_uses_appearance_peak_fraction(
        rng, params, image, fraction):
    crop = np.full((10, 12, 3), RED, np.uint8)
    det = registry.load("detectors", "dtdmi", {**params, "use_dynamic": False},
                        appearance=crop if image else None)
    img = _two_boxes(rng, True, 0)
    for i in range(3):
        res = det.detect(_frame(img, i))
    peak8 = float(np.round(res.saliency.max() * 255.0))
    assert peak8 * fraction > 20  # above the aerial floor: the fraction sets T
    assert res.threshold == pytest.approx(fraction * peak8 / 255.0, abs=1.5 / 255.0)


def test_with_an_image_no_region_below_appearance_floor(rng):
    """The image-weighted map below ``appearance_floor`` everywhere: no region (no target);
    the aerial preset's floor with an image is 30, without one regions.adaptive_floor (20)."""
    crop = np.full((10, 12, 3), RED, np.uint8)
    img = _two_boxes(rng, True, 0)

    def run(params, image=True):
        det = registry.load("detectors", "dtdmi", {"preset": "aerial", "use_dynamic": False,
                                                   **params},
                            appearance=crop if image else None)
        for i in range(3):
            res = det.detect(_frame(img, i))
        return res

    peak8 = float(np.round(run({}).saliency.max() * 255.0))
    below, above = run({"appearance_floor": int(peak8) + 2}), run({"appearance_floor": 1})
    assert below.detections == () and below.threshold == pytest.approx((peak8 + 2) / 255.0,
                                                                        abs=1e-6)
    assert above.detections != ()  # T = 0.7 x the peak
    assert above.threshold == pytest.approx(0.7 * peak8 / 255.0, abs=1.5 / 255.0)
    plain = DTDMIConfig(preset="aerial")
    assert resolve(plain).appearance_floor == 30 and plain.regions.adaptive_floor == 20
