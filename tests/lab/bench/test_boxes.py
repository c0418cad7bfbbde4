"""Box annotations and the box metrics of ``bench`` (hand-computed cases)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.lab.bench.boxes import (
    BoxFormatError,
    BoxScores,
    box_from_mask,
    crop_box,
    detection_iou,
    grow_box,
    parse_boxes,
    peak_on_target,
    point_in_box,
    polygon_iou,
    score_frame,
    spread,
)

from eaglemission.geometry import order_corners
from eaglemission.types import Detection, DetectionResult


def _det(u0: float, v0: float, u1: float, v1: float, score: float = 1.0) -> Detection:
    corners = order_corners(np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], float))
    return Detection(score=score, center_px=((u0 + u1) / 2, (v0 + v1) / 2), corners_px=corners,
                     size_px=(max(u1 - u0, v1 - v0), min(u1 - u0, v1 - v0)), angle_deg=0.0,
                     area_px=(u1 - u0) * (v1 - v0))


def _result(dets, sal=None) -> DetectionResult:
    if sal is None:
        sal = np.zeros((100, 200), np.float32)
    return DetectionResult(sal, tuple(dets), 0, "t", 0)


def test_parse_boxes_one_based_nan_and_separators():
    text = "1,1,10,4\n11\t21\t5\t6\nnan,nan,nan,nan\nNaN NaN NaN NaN\n3;4;2;2\n\n"
    b = parse_boxes(text)
    assert b.shape == (5, 4)
    # 1-based x = 1, w = 10: pixel centres 0..9, edges -0.5 .. 9.5
    np.testing.assert_allclose(b[0], [-0.5, -0.5, 9.5, 3.5])
    np.testing.assert_allclose(b[1], [9.5, 19.5, 14.5, 25.5])
    assert np.isnan(b[2]).all() and np.isnan(b[3]).all()
    np.testing.assert_allclose(b[4], [1.5, 2.5, 3.5, 4.5])


def test_parse_boxes_zero_based_is_one_pixel_right_and_down():
    one = parse_boxes("5,7,3,2", origin=1)[0]
    zero = parse_boxes("5,7,3,2", origin=0)[0]
    np.testing.assert_allclose(zero - one, [1, 1, 1, 1])
    np.testing.assert_allclose(zero, [4.5, 6.5, 7.5, 8.5])


@pytest.mark.parametrize("text, message", [
    ("1,2,3\n", "expected x,y,w,h"),
    ("1,2,3,x\n", "not a number"),
    ("1,2,0,4\n", "w, h > 0"),
    ("1,2,-3,4\n", "w, h > 0"),
    ("1,2,3,4\n\n1,2,3,4\n", "expected x,y,w,h"),  # an inner blank line would shift frames
    ("1,2,inf,4\n", "finite"),
])
def test_parse_boxes_errors_name_the_line(text, message):
    with pytest.raises(BoxFormatError, match=message) as exc:
        parse_boxes(text, source="seq/boxes.txt")
    assert "seq/boxes.txt:" in str(exc.value)


def test_parse_boxes_rejects_bad_origin():
    with pytest.raises(ValueError, match="origin"):
        parse_boxes("1,1,1,1", origin=2)


def test_grow_box_and_point_in_box():
    g = grow_box(np.array([10.0, 20.0, 30.0, 60.0]))  # 20 x 40: +5 / +10 each side
    np.testing.assert_allclose(g, [5, 10, 35, 70])
    assert point_in_box(5.0, 10.0, g) and point_in_box(35.0, 70.0, g)  # edges count
    assert not point_in_box(4.99, 40.0, g) and not point_in_box(20.0, 70.01, g)


def test_polygon_iou_hand_computed():
    a = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)
    b = a + [1, 0]  # overlap 1 x 2 = 2, union 4 + 4 - 2 = 6
    assert polygon_iou(a, b) == pytest.approx(1 / 3)
    assert polygon_iou(a, a) == pytest.approx(1.0)
    assert polygon_iou(a, a + [5, 5]) == 0.0
    # a 45-degree square of half-diagonal 1 inside a 2 x 2 square: area 2 / 4
    diamond = np.array([[1, 0], [2, 1], [1, 2], [0, 1]], float)
    assert polygon_iou(a, diamond) == pytest.approx(0.5)
    d = _det(0, 0, 2, 2)
    assert detection_iou(d, np.array([1.0, 0.0, 3.0, 2.0])) == pytest.approx(1 / 3)


def test_peak_on_target():
    sal = np.zeros((50, 80), np.float32)
    sal[20, 30] = 1.0
    box = np.array([25.0, 15.0, 35.0, 25.0])
    assert peak_on_target(sal, box)
    assert not peak_on_target(sal, box + [10, 0, 10, 0])
    assert not peak_on_target(np.full((50, 80), 0.7, np.float32), box)  # no peak at all
    sal[40, 70] = 1.0  # a tie elsewhere still counts
    assert peak_on_target(sal, box)
    # a pixel centre on the grown box's edge is inside; one just outside is not
    sal2 = np.zeros((50, 80), np.float32)
    sal2[10, 40] = 1.0
    assert peak_on_target(sal2, np.array([40.0, 10.0, 45.0, 12.0]))
    assert not peak_on_target(sal2, np.array([40.2, 10.0, 45.0, 12.0]))
    assert not peak_on_target(sal2, np.array([-30.0, -30.0, -10.0, -10.0]))  # off the image


def test_score_frame_hand_computed():
    box = np.array([100.0, 40.0, 140.0, 60.0])  # 40 x 20, grown: 90..150 x 35..65
    best = _det(120, 45, 150, 65)  # centre (135, 55): inside; IoU: 20 x 15 / (800 + 600 - 300)
    miss = _det(0, 0, 10, 10)  # centre (5, 5): false
    edge = _det(146, 60, 154, 70)  # centre (150, 65): on the grown edge -> on target
    sal = np.zeros((100, 200), np.float32)
    sal[50, 120] = 1.0
    s = score_frame(_result([best, miss, edge], sal), box)
    assert s.has_target and s.best_on_target and s.peak_on_target
    assert s.iou == pytest.approx(300 / 1100)
    assert (s.n_detections, s.n_false) == (3, 1)
    # the best ranked one misses: not on target even though another one hits
    s2 = score_frame(_result([miss, best]), box)
    assert not s2.best_on_target and s2.n_false == 1 and s2.iou == 0.0
    # no target in the frame: every detection is false
    s3 = score_frame(_result([best, miss]), np.full(4, np.nan))
    assert not s3.has_target and s3.n_false == 2
    # no detection
    s4 = score_frame(_result([]), box)
    assert s4.has_target and not s4.best_on_target and s4.iou == 0.0 and s4.n_false == 0


def test_box_scores_aggregate():
    box = np.array([100.0, 40.0, 140.0, 60.0])
    acc = BoxScores()
    acc.add(score_frame(_result([_det(110, 45, 130, 55), _det(0, 0, 8, 8)]), box))  # hit, 1 false
    acc.add(score_frame(_result([_det(0, 0, 8, 8)]), box))  # miss, 1 false
    acc.add(score_frame(_result([]), box))  # nothing
    acc.add(score_frame(_result([_det(0, 0, 8, 8)]), np.full(4, np.nan)))  # no target, 1 false
    assert acc.frames == 4 and acc.target_frames == 3
    assert acc.on_target_rate == pytest.approx(1 / 3)
    assert acc.any_rate == pytest.approx(2 / 3)
    assert acc.false_per_frame == pytest.approx(3 / 4)
    assert acc.mean_iou == pytest.approx((200 / 800) / 3)
    other = BoxScores()
    other.merge(acc)
    assert other.as_dict() == acc.as_dict()
    assert math.isnan(BoxScores().on_target_rate)


def test_spread_ignores_nan():
    s = spread([0.2, float("nan"), 0.4])
    assert s["mean"] == pytest.approx(0.3) and s["min"] == 0.2 and s["max"] == 0.4
    assert s["std"] == pytest.approx(0.1)
    assert math.isnan(spread([])["mean"])


def test_box_from_mask_and_crop_round_trip():
    mask = np.zeros((30, 40), bool)
    mask[5:9, 10:20] = True
    box = box_from_mask(mask)
    np.testing.assert_allclose(box, [9.5, 4.5, 19.5, 8.5])
    assert np.isnan(box_from_mask(np.zeros((3, 3), bool))).all()
    img = np.zeros((30, 40, 3), np.uint8)
    img[mask] = (1, 2, 3)
    crop = crop_box(img, box)
    assert crop.shape == (4, 10, 3) and (crop == (1, 2, 3)).all()
    # the 1-based annotation of the same pixels crops the same block
    one_based = parse_boxes("11,6,10,4")[0]
    np.testing.assert_allclose(one_based, box)
    with pytest.raises(ValueError, match="outside"):
        crop_box(img, np.array([50.0, 50.0, 60.0, 60.0]))
