"""Regions: corner order, thresholds, MBR, prior filter, ranking; base-class frame handling."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from eaglemission.detectors.base import SaliencyDetector, validate_image

from eaglemission.errors import InputError
from eaglemission.geometry import order_corners
from eaglemission.perception.regions import (
    RegionsConfig,
    binarize,
    find_regions,
    long_side_angle_deg,
    prior_accepts,
    to_uint8,
)
from eaglemission.types import Frame, TargetPrior


def _shoelace(c: np.ndarray) -> float:
    u, v = c[:, 0], c[:, 1]
    return float(np.sum(u * np.roll(v, -1) - np.roll(u, -1) * v))


def test_order_corners_axis_aligned(rng):
    tl, tr, br, bl = [0, 0], [10, 0], [10, 5], [0, 5]
    for _ in range(10):
        pts = np.array([tl, tr, br, bl], float)[rng.permutation(4)]
        np.testing.assert_array_equal(order_corners(pts), [tl, tr, br, bl])


def test_order_corners_diamond_tie_breaks_on_v():
    # top (5,0) and left (0,5) both have u + v = 5: the smaller v (top) comes first
    top, right, bottom, left = [5, 0], [10, 5], [5, 10], [0, 5]
    out = order_corners(np.array([left, bottom, right, top], float))
    np.testing.assert_array_equal(out, [top, right, bottom, left])
    # float noise on the tie does not flip it
    out = order_corners(np.array([[0, 5 + 1e-9], [5, 10], [10, 5], [5 - 1e-9, 0]]))
    assert out[0, 1] == pytest.approx(0.0)


def test_order_corners_random_rotated_rectangles(rng):
    for _ in range(200):
        rect = ((rng.uniform(50, 500), rng.uniform(50, 500)),
                (rng.uniform(2, 80), rng.uniform(2, 80)), rng.uniform(-180, 180))
        pts = cv2.boxPoints(rect).astype(float)[rng.permutation(4)]
        out = order_corners(pts)
        assert _shoelace(out) > 0  # clockwise on screen (v down)
        s = out.sum(axis=1)
        assert s[0] <= s.min() + 1e-6
        assert sorted(map(tuple, out)) == sorted(map(tuple, pts))


def test_fixed_threshold_is_strictly_above_T():
    sal = np.zeros((40, 40), np.float32)
    sal[5:15, 5:15] = 120 / 255  # == T: not in the region
    sal[20:30, 20:30] = 121 / 255
    mask, t = binarize(to_uint8(sal), RegionsConfig())
    assert t == 120
    assert not mask[5:15, 5:15].any() and mask[20:30, 20:30].all()
    dets, thr = find_regions(sal, RegionsConfig())
    assert thr == pytest.approx(120 / 255) and len(dets) == 1


def test_otsu_and_mean_thresholds(rng):
    sal = np.where(rng.rand(60, 60) < 0.5, 0.2, 0.8).astype(np.float32)
    _, t = binarize(to_uint8(sal), RegionsConfig(threshold="otsu"))
    assert 51 <= t < 204
    sal8 = np.full((10, 10), 20, np.uint8)
    _, t = binarize(sal8, RegionsConfig(threshold="mean", mean_factor=3.0))
    assert t == pytest.approx(60.0)
    _, t = binarize(np.full((4, 4), 200, np.uint8), RegionsConfig(threshold="mean"))
    assert t == 254.0  # clamped


def test_normalize_none_vs_minmax():
    sal = np.zeros((50, 50), np.float32)
    sal[10:20, 10:20] = 0.3  # weak everywhere: below T when taken as given
    assert find_regions(sal, RegionsConfig())[0] == ()
    assert len(find_regions(sal, RegionsConfig(normalize="minmax"))[0]) == 1
    assert find_regions(np.zeros((8, 8), np.float32), RegionsConfig(normalize="minmax"))[0] == ()


def test_to_uint8_saturates_and_zeroes_nan():
    s = np.array([[np.nan, -0.5, 0.2, 1.5, 1.0]], np.float32)
    np.testing.assert_array_equal(to_uint8(s), [[0, 0, 51, 255, 255]])
    # NaN alone (nothing negative), negative alone, neither
    np.testing.assert_array_equal(to_uint8(np.array([[np.nan, 0.2]], np.float32)), [[0, 51]])
    np.testing.assert_array_equal(to_uint8(np.array([[-0.1, 0.2]], np.float32)), [[0, 51]])
    np.testing.assert_array_equal(to_uint8(np.array([[0.0, 0.5]], np.float32)), [[0, 128]])


def test_mbr_of_axis_aligned_block_lies_on_pixel_edges():
    sal = np.zeros((40, 60), np.float32)
    sal[10:16, 20:30] = 1.0  # 10 px wide, 6 px tall: columns 20..29, rows 10..15
    (d,), _ = find_regions(sal, RegionsConfig())
    assert d.size_px == pytest.approx((10.0, 6.0))
    assert d.center_px == pytest.approx((24.5, 12.5))
    np.testing.assert_allclose(d.corners_px, [[19.5, 9.5], [29.5, 9.5], [29.5, 15.5], [19.5, 15.5]])
    assert d.area_px == pytest.approx(60.0)
    assert d.angle_deg == pytest.approx(0.0)
    (d,), _ = find_regions(sal, RegionsConfig(mbr_pixel_edges=False))
    assert d.size_px == pytest.approx((9.0, 5.0))  # pixel centres


def test_a_region_keeps_the_convex_hull_of_its_outline():
    """An L-shaped region: its MBR is the full 30 x 30 square, its hull cuts the empty corner
    (the silhouette check compares that outline with the target's shape)."""
    sal = np.zeros((60, 60), np.float32)
    sal[10:40, 10:20] = 1.0
    sal[30:40, 10:40] = 1.0
    (d,), _ = find_regions(sal, RegionsConfig())
    assert d.hull_px is not None and d.hull_px.shape[1] == 2
    hull_area = cv2.contourArea(d.hull_px.astype(np.float32))
    # pixels 10..39 / 10..19 / 30..39 as squares (edges 9.5..39.5): the square less the corner
    # triangle with 20 px legs
    assert hull_area == pytest.approx(30 * 30 - 0.5 * 20 * 20, abs=1e-6)
    (e,), _ = find_regions(sal, RegionsConfig(mbr_pixel_edges=False))
    assert cv2.contourArea(e.hull_px.astype(np.float32)) == pytest.approx(29 * 29 - 0.5 * 20 * 20)
    assert d.size_px == pytest.approx((30.0, 30.0))


@pytest.mark.parametrize("angle", [-60.0, -25.0, 0.0, 30.0, 75.0])
def test_mbr_of_rotated_rectangle(angle):
    # area-correct rasterisation: coverage of each pixel, from an 8x supersampled drawing
    big = np.zeros((2400, 2400), np.float32)
    pts = cv2.boxPoints(((150.0 * 8 + 3.5, 140.0 * 8 + 3.5), (120.0 * 8, 50.0 * 8), angle))
    cv2.fillPoly(big, [np.round(pts).astype(np.int32)], 1.0)
    sal = cv2.resize(big, (300, 300), interpolation=cv2.INTER_AREA)
    (d,), _ = find_regions(sal, RegionsConfig())
    assert d.size_px[0] == pytest.approx(120.0, abs=1.5)
    assert d.size_px[1] == pytest.approx(50.0, abs=1.5)
    assert d.center_px == pytest.approx((150.0, 140.0), abs=1.0)
    diff = (d.angle_deg - angle + 90.0) % 180.0 - 90.0
    assert abs(diff) < 1.5
    assert -90.0 <= d.angle_deg < 90.0
    assert _shoelace(d.corners_px) > 0


def test_long_side_angle():
    c = order_corners(np.array([[0, 0], [2, 2], [-8, 12], [-10, 10]], float))
    assert long_side_angle_deg(c) == pytest.approx(-45.0) or \
        long_side_angle_deg(c) == pytest.approx(135.0 - 180.0)


def test_prior_filter_area_and_aspect():
    sal = np.zeros((200, 200), np.float32)
    sal[10:20, 10:30] = 1.0    # 20 x 10: area 200, aspect 2
    sal[50:90, 50:90] = 1.0    # 40 x 40: area 1600, aspect 1
    sal[120:122, 20:80] = 1.0  # 60 x 2: aspect 30
    cfg = RegionsConfig()
    assert len(find_regions(sal, cfg)[0]) == 3
    dets, _ = find_regions(sal, cfg, TargetPrior(min_area_px=150, max_area_px=500))
    assert [d.size_px for d in dets] == [pytest.approx((20.0, 10.0))]
    dets, _ = find_regions(sal, cfg, TargetPrior(aspect_ratio=1.8, aspect_tolerance=0.2))
    assert [d.size_px for d in dets] == [pytest.approx((20.0, 10.0))]
    dets, _ = find_regions(sal, cfg, TargetPrior(aspect_ratio=1.0, aspect_tolerance=0.1))
    assert [d.size_px for d in dets] == [pytest.approx((40.0, 40.0))]
    assert prior_accepts(100.0, 10.0, 0.0, None)
    assert not prior_accepts(100.0, 10.0, 0.0, TargetPrior(aspect_ratio=2.0))
    assert prior_accepts(100.0, 10.0, 0.0, TargetPrior())


def test_min_area_and_ranking():
    sal = np.zeros((100, 100), np.float32)
    sal[5:8, 5:8] = 1.0         # 9 px: below min_area_px 16
    sal[20:30, 20:30] = 0.6     # 100 px, mean 0.6 -> score 6
    sal[50:54, 50:54] = 1.0     # 16 px, mean 1.0 -> score 4
    sal[70:90, 70:90] = 0.5     # 400 px, mean 0.5 -> score 10
    dets, _ = find_regions(sal, RegionsConfig())
    assert [round(d.score, 3) for d in dets] == [10.0, 6.0, 4.0]
    assert dets[0].center_px == pytest.approx((79.5, 79.5))
    dets, _ = find_regions(sal, RegionsConfig(max_detections=2))
    assert len(dets) == 2


def test_region_score_ignores_other_regions_in_its_bounding_box():
    sal = np.zeros((60, 60), np.float32)
    sal[10:50, 10:15] = 0.5   # an L ...
    sal[45:50, 10:50] = 0.5
    sal[20:30, 30:40] = 1.0   # ... and a blob inside its bounding box, outside its outline
    dets, _ = find_regions(sal, RegionsConfig())
    ell = max(dets, key=lambda d: d.area_px)
    assert ell.score == pytest.approx(0.5 * math.sqrt(40 * 5 + 35 * 5), rel=1e-3)


# -- base class -----------------------------------------------------------------------------
class _Counting(SaliencyDetector):
    description = "test"

    def __init__(self, config=None, **context):
        super().__init__(config, **context)
        self.resets = 0

    def _reset(self):
        self.resets += 1

    def _saliency(self, image, frame):
        return np.zeros(image.shape[:2], np.float32)


def test_validate_image_errors_and_grey():
    with pytest.raises(InputError, match="uint8"):
        validate_image(np.zeros((10, 10, 3), np.float32))
    with pytest.raises(InputError, match=r"\(H, W, 3\)"):
        validate_image(np.zeros((10, 10, 4), np.uint8))
    with pytest.raises(InputError, match="at least 8x8"):
        validate_image(np.zeros((4, 10, 3), np.uint8))
    with pytest.raises(InputError, match="numpy array"):
        validate_image([[1, 2]])
    assert validate_image(np.zeros((10, 12), np.uint8)).shape == (10, 12, 3)


def test_resolution_change_resets_state():
    det = _Counting()
    det.detect(Frame(np.zeros((20, 30, 3), np.uint8), 0, "wide", 0))
    det.detect(Frame(np.zeros((20, 30, 3), np.uint8), 1, "wide", 1))
    assert det.resets == 0
    det.detect(Frame(np.zeros((24, 30), np.uint8), 2, "wide", 2))
    assert det.resets == 1
    det.reset()
    assert det.resets == 2


def test_adaptive_threshold_hand_computed():
    from eaglemission.perception.regions import adaptive_threshold

    assert adaptive_threshold(200.0, 40, 0.8) == pytest.approx(160.0)
    assert adaptive_threshold(30.0, 40, 0.8) == 40.0  # the floor
    cfg = RegionsConfig(threshold="adaptive", adaptive_floor=40, peak_fraction=0.5)
    sal8 = np.zeros((20, 30), np.uint8)
    sal8[5:9, 5:9] = 200
    sal8[12:15, 20:26] = 90  # below 0.5 x 200
    mask, t = binarize(sal8, cfg)
    assert t == 100.0 and mask[6, 6] == 255 and mask[13, 22] == 0
    sal8[5:9, 5:9] = 60  # now the peak is the 90 block: T = max(40, 45)
    mask, t = binarize(sal8, cfg)
    assert t == 45.0 and mask[6, 6] == 255 and mask[13, 22] == 255
    sal8[12:15, 20:26] = 30
    assert binarize(sal8, cfg)[1] == 40.0  # 0.5 x 60 < the floor


def test_adaptive_regions_fire_on_a_weak_blob_and_stay_silent_on_a_flat_map():
    cfg = RegionsConfig(threshold="adaptive", adaptive_floor=40, peak_fraction=0.8)
    sal = np.full((60, 80), 0.05, np.float32)  # 13 on 0..255: below the floor
    assert find_regions(sal, cfg)[0] == ()
    sal[20:28, 30:40] = 0.3  # a weak blob (77): below T = 120, found by the adaptive rule
    dets, t = find_regions(sal, cfg)
    assert find_regions(sal, RegionsConfig())[0] == ()
    assert len(dets) == 1 and t == pytest.approx(0.8 * 0.3, abs=1 / 255)
    assert dets[0].size_px == pytest.approx((10.0, 8.0))


def test_shape_filters_drop_elongated_and_huge_regions():
    sal = np.zeros((100, 200), np.float32)
    sal[10:14, 10:110] = 0.9  # 100 x 4: aspect 25
    sal[50:90, 20:180] = 0.8  # 160 x 40: 32 % of the image
    sal[60:70, 190:198] = 0.7  # 8 x 10
    base = RegionsConfig()
    assert len(find_regions(sal, base)[0]) == 3
    dets = find_regions(sal, base.model_copy(update={"max_aspect": 5.0}))[0]
    assert len(dets) == 2 and all(d.size_px[0] <= 5 * d.size_px[1] for d in dets)
    dets = find_regions(sal, base.model_copy(update={"max_area_frac": 0.1}))[0]
    assert len(dets) == 2 and all(d.area_px <= 0.1 * 200 * 100 for d in dets)


@pytest.mark.parametrize("angle_deg", [0.0, 25.0])
def test_regions_of_a_reduced_map_in_frame_pixels(angle_deg):
    """A rectangle found on the map reduced by 2 (area average) and mapped back equals the one
    found on the full map within a frame pixel; sizes, area and the hull follow."""
    from eaglemission.perception.regions import reduced_prior, to_frame_pixels

    full = np.zeros((240, 320), np.float32)
    rect = ((161.5, 100.5), (80.0, 40.0), angle_deg)
    cv2.fillPoly(full, [np.round(cv2.boxPoints(rect)).astype(np.int32)], 1.0)
    half = cv2.resize(full, (160, 120), interpolation=cv2.INTER_AREA)
    cfg = RegionsConfig(fixed_threshold=127)
    (ref,), _ = find_regions(full, cfg)
    (small,), _ = find_regions(half, cfg, reduced_prior(TargetPrior(min_area_px=400.0), 2, 2))
    got = to_frame_pixels(small, 2.0, 2.0)
    np.testing.assert_allclose(got.corners_px, ref.corners_px, atol=1.5)
    np.testing.assert_allclose(got.center_px, ref.center_px, atol=1.0)
    np.testing.assert_allclose(got.size_px, ref.size_px, rtol=0.05)
    assert got.area_px == pytest.approx(ref.area_px, rel=0.06)
    assert got.score == pytest.approx(ref.score, rel=0.06)
    assert got.hull_px is not None and got.hull_px[:, 0].min() == pytest.approx(
        ref.hull_px[:, 0].min(), abs=1.5)
    # the prior's areas are in frame pixels: a 1600 px^2 minimum drops the 3200 px^2 box's
    # half-resolution region only when it is not reduced
    assert find_regions(half, cfg, TargetPrior(min_area_px=1600.0))[0] == ()
    assert find_regions(half, cfg, reduced_prior(TargetPrior(min_area_px=1600.0), 2, 2))[0]
