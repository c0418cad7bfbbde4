"""The appearance prior stage after any detector (eaglemission/perception/prior.py) and the
target's appearance modelled once (eaglemission/perception/appearance.py)."""

from __future__ import annotations

import numpy as np
import pytest

from eaglemission import registry
from eaglemission.clock import ManualClock
from eaglemission.config import TargetConfig, load_config
from eaglemission.errors import ConfigError, InputError
from eaglemission.flight.assembly import assemble, target_appearance
from eaglemission.perception.appearance import AppearanceConfig, TargetAppearance
from eaglemission.perception.prior import (
    AppearancePrior,
    PriorConfig,
    combined_map,
    spotlit_saliency,
)
from eaglemission.perception.regions import find_regions
from eaglemission.types import Frame

GREEN = (60, 140, 70)
BROWN = (60, 80, 110)


def _ground(rng: np.random.RandomState, h: int = 240, w: int = 320) -> np.ndarray:
    img = np.empty((h, w, 3), np.float32)
    img[...] = GREEN
    img += rng.randn(h, w, 3).astype(np.float32) * 6
    return np.clip(img, 0, 255).astype(np.uint8)


def test_combined_map_is_the_weighted_mean():
    a = np.array([[0.0, 1.0, 0.5]], np.float32)
    s = np.array([[1.0, 0.0, 0.5]], np.float32)
    np.testing.assert_allclose(combined_map(a, s, 3.0), [[0.75, 0.25, 0.5]], rtol=1e-6)
    np.testing.assert_allclose(combined_map(a, s, 0.0), a)


def test_spotlit_saliency_matches_the_formula(rng):
    sal = rng.rand(40, 30).astype(np.float32)
    out = spotlit_saliency(sal, (12.0, 20.0), 5.0, 0.4)
    v, u = np.mgrid[0:40, 0:30]
    g = np.exp(-((u - 12.0) ** 2 + (v - 20.0) ** 2) / (2 * 25.0))
    np.testing.assert_allclose(out, sal * (0.6 + 0.4 * g), rtol=1e-5)
    np.testing.assert_array_equal(spotlit_saliency(sal, (5.0, 5.0), 3.0, 0.0), sal)
    with pytest.raises(ValueError, match="strength"):
        spotlit_saliency(sal, (5.0, 5.0), 3.0, -0.1)
    with pytest.raises(ValueError, match="sigma"):
        spotlit_saliency(sal, (5.0, 5.0), 0.0, 0.5)


@pytest.mark.parametrize("name,params", [("dtdmi", {"preset": "aerial", "use_dynamic": False}),
                                         ("sr", {})])
def test_the_prior_puts_the_target_before_a_more_salient_distractor(rng, name, params):
    """A dull brown target and a saturated magenta distractor of the same size on grass: the
    detector alone ranks the distractor first; followed by the appearance prior with the
    target's example image, the target comes first. Any detector: DTDMI and OpenCV's SR."""
    frame = _ground(rng, 240, 320)
    frame[60:72, 40:60] = BROWN
    frame[160:172, 220:240] = (255, 0, 255)
    crop = np.full((16, 24, 3), BROWN, np.uint8)
    plain = registry.load("detectors", name, params)
    # the weight of the detector's map as tuned for each (benchmarks/tune_real.py: SR's
    # per-frame-normalised map takes less)
    weight = 2.0 if name == "dtdmi" else 0.25
    prior = TargetAppearance(image=crop).with_prior(registry.load("detectors", name, params),
                                                    PriorConfig(downscale=1,
                                                                saliency_weight=weight))
    assert isinstance(prior, AppearancePrior)
    r0 = plain.detect(Frame(frame, 1_000_000_000, "w", 0))
    r1 = prior.detect(Frame(frame, 1_000_000_000, "w", 0))
    assert r1.best is not None
    u1, v1 = r1.best.center_px
    assert 40 <= u1 <= 60 and 60 <= v1 <= 72  # the target
    if name == "dtdmi":
        assert r0.best is not None
        u0, v0 = r0.best.center_px
        assert 220 <= u0 <= 240 and 160 <= v0 <= 172  # the distractor


def test_the_prior_finds_its_regions_at_the_processing_resolution(rng):
    """``downscale`` 2: regions on the half-resolution map, reported in the frame's pixels: the
    same rectangles as on the full-resolution map the result holds."""
    frame = _ground(rng, 480, 640)
    frame[200:236, 300:360] = (30, 40, 210)
    crop = frame[195:241, 295:365].copy()
    cfg = PriorConfig(downscale=2)
    det = TargetAppearance(image=crop).with_prior(
        registry.load("detectors", "dtdmi", {"preset": "aerial", "use_dynamic": False,
                                             "downscale": 2}), cfg)
    for k in range(2):
        res = det.detect(Frame(frame, 1_000_000_000 + k * 33_000_000, "w", k))
    assert res.saliency.shape == (480, 640) and res.best is not None
    u, v = res.best.center_px
    assert 300 <= u <= 360 and 200 <= v <= 236
    full, _ = find_regions(res.saliency, cfg.regions)
    assert full
    np.testing.assert_allclose(res.best.corners_px, full[0].corners_px, atol=2.0)


def test_the_prior_follows_its_previous_best_detection(rng):
    frame = _ground(rng)
    frame[60:76, 40:64] = BROWN
    frame[160:176, 220:244] = BROWN  # a twin
    det = TargetAppearance(image=np.full((16, 24, 3), BROWN, np.uint8)).with_prior(
        registry.load("detectors", "sr", {}), PriorConfig(downscale=1, saliency_weight=0.25,
                                                          follow_weight=0.5))
    first = det.detect(Frame(frame, 1, "w", 0)).best
    assert first is not None and det.follow_px is not None
    again = det.detect(Frame(frame, 2, "w", 1)).best
    assert again is not None and np.allclose(again.center_px, first.center_px, atol=2)
    det.reset()
    assert det.follow_px is None


def test_without_an_example_image_or_with_the_prior_off_the_detector_runs_alone():
    sr = registry.load("detectors", "sr", {})
    assert TargetAppearance(colour_bgr=(1, 2, 3)).with_prior(sr, PriorConfig()) is sr
    assert TargetAppearance(image=np.zeros((8, 8, 3), np.uint8)).with_prior(sr, None) is sr


def test_the_prior_refuses_frames_without_colour():
    det = TargetAppearance(image=np.zeros((8, 8, 3), np.uint8)).with_prior(
        registry.load("detectors", "sr", {}), PriorConfig())
    with pytest.raises(InputError, match="8-bit BGR"):
        det.detect(Frame(np.zeros((32, 32), np.uint8), 1, "w", 0))


def test_the_assembly_models_the_appearance_once_for_both_cameras_and_the_mission():
    """The embedded mission: one TargetAppearance from target.color_bgr and
    target.appearance_image, the prior after each camera's detector, the same object to the
    mission."""
    cfg = load_config()
    asm = assemble(cfg, ManualClock())
    assert asm.appearance is not None and asm.appearance.has_model and asm.appearance.has_colour
    for det in asm.detectors.values():
        assert isinstance(det, AppearancePrior) and det.model is asm.appearance.model
    assert asm.parts(realtime=False).appearance is asm.appearance
    off = cfg.model_copy(update={"appearance": AppearanceConfig(prior=None)})
    assert not any(isinstance(d, AppearancePrior) for d in assemble(
        off, ManualClock()).detectors.values())
    bare = cfg.model_copy(update={"target": TargetConfig(length_m=0.4, width_m=0.25)})
    assert target_appearance(bare) is None


def test_an_unreadable_example_image_names_its_key(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"not an image")
    cfg = load_config()
    bad = cfg.model_copy(update={"target": cfg.target.model_copy(
        update={"appearance_image": str(tmp_path / "bad.png")})})
    with pytest.raises(ConfigError, match="target.appearance_image: cannot read"):
        assemble(bad, ManualClock())


RED = (30, 40, 210)


def _two_boxes(rng: np.random.RandomState, left: bool, right_size: int) -> np.ndarray:
    img = np.empty((120, 200, 3), np.float32)
    img[...] = GREEN
    img += rng.randn(120, 200, 3).astype(np.float32) * 4
    img = np.clip(img, 0, 255).astype(np.uint8)
    if left:
        img[50:60, 30:42] = RED
    img[50:50 + right_size, 150:150 + right_size + 2] = RED
    return img


def _aerial(follow: float, **prior) -> AppearancePrior:
    det = TargetAppearance(image=np.full((10, 12, 3), RED, np.uint8)).with_prior(
        registry.load("detectors", "dtdmi", {"preset": "aerial", "use_dynamic": False}),
        PriorConfig(downscale=1, follow_weight=follow, **prior))
    assert isinstance(det, AppearancePrior)
    return det


def test_following_the_previous_best_detection_keeps_the_target(rng):
    """Frames 0-2: one red box (left) only; frame 3 adds a bigger red box (right). Without
    following, the bigger box wins frame 3; following the previous best keeps the left one."""
    frames = [_two_boxes(rng, True, 0) for _ in range(3)] + [_two_boxes(rng, True, 16)]
    best = {}
    for weight in (0.0, 0.6):
        det = _aerial(weight)
        for i, f in enumerate(frames):
            res = det.detect(Frame(f, 1_000_000_000 + i * 100_000_000, "w", i))
        assert res.best is not None
        best[weight] = res.best.center_px
    assert best[0.0][0] > 140  # the bigger box on the right
    assert best[0.6][0] < 50  # the box it was following


def test_following_needs_a_previous_detection(rng):
    """The first frame after a reset (no previous detection) is not attenuated."""
    f = Frame(_two_boxes(rng, True, 16), 1_000_000_000, "w", 0)
    np.testing.assert_array_equal(_aerial(0.6).detect(f).saliency,
                                  _aerial(0.0).detect(f).saliency)


def test_no_region_below_the_floor_and_the_peak_fraction_above_it(rng):
    img = _two_boxes(rng, True, 0)

    def run(floor: int) -> object:
        det = _aerial(0.0, regions={"threshold": "adaptive", "adaptive_floor": floor,
                                    "peak_fraction": 0.7})
        return det.detect(Frame(img, 1_000_000_000, "w", 0))

    peak8 = float(np.round(run(1).saliency.max() * 255.0))
    below, above = run(int(peak8) + 2), run(1)
    assert below.detections == () and below.threshold == pytest.approx((peak8 + 2) / 255.0,
                                                                        abs=1e-6)
    assert above.detections != ()
    assert above.threshold == pytest.approx(0.7 * peak8 / 255.0, abs=1.5 / 255.0)


def test_unpooled_colour_model_keeps_the_exact_bins():
    from eaglemission.perception.appearance import ExampleModelConfig
    from eaglemission.perception.colour_bins import quantize_bgr

    crop = np.zeros((12, 12, 3), np.uint8)
    crop[...] = RED
    crop[:, 6:] = (200, 90, 20)
    pooled = TargetAppearance(image=crop, example=ExampleModelConfig(pool=True,
                                                                     exposure_span=1.0))
    exact = TargetAppearance(image=crop, example=ExampleModelConfig(exposure_span=1.0))
    assert pooled.model is not None and exact.model is not None
    assert pooled.model.pool and not exact.model.pool
    bins = set(np.unique(quantize_bgr(crop)).tolist())
    assert set(np.flatnonzero(exact.model.q).tolist()) <= bins
    assert np.count_nonzero(pooled.model.q) > 2 * len(bins)
    spanned = TargetAppearance(image=crop)  # the default span: 1.5
    assert spanned.model is not None and len(spanned.model.q_exposures) > 1
