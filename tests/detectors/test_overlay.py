"""The overlay picture of ``eaglemission detect`` (eaglemission.perception.overlay): labels
never over a box, colour only where the map is salient, the frame at its own coordinates."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from eaglemission.geometry import order_corners
from eaglemission.perception.overlay import MIN_WIDTH_PX, draw_overlay, threshold_uint8
from eaglemission.types import Detection, DetectionResult


def _detection(cx: float, cy: float, w: float, h: float, angle_deg: float,
               score: float) -> Detection:
    pts = cv2.boxPoints(((cx, cy), (w, h), angle_deg)).astype(np.float64)
    return Detection(score=score, center_px=(cx, cy), corners_px=order_corners(pts),
                     size_px=(max(w, h), min(w, h)), angle_deg=angle_deg, area_px=w * h)


def _interior(shape: tuple[int, int], corners: np.ndarray, erode_px: int) -> np.ndarray:
    """Pixels inside the polygon, at least ``erode_px`` from its outline."""
    mask = np.zeros(shape, np.uint8)
    cv2.fillPoly(mask, [np.round(corners).astype(np.int32)], 255)
    k = 2 * erode_px + 1
    return cv2.erode(mask, np.ones((k, k), np.uint8)) > 0


def _frame(rng: np.random.RandomState, w: int, h: int) -> np.ndarray:
    return np.clip(rng.randn(h, w, 3) * 20 + 110, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("where", ["centre", "top-left corner", "crowded"])
def test_labels_and_corner_numbers_never_cover_a_box(rng, where):
    w, h = 320, 240
    img = _frame(rng, w, h)
    if where == "centre":
        dets = [_detection(160, 120, 40, 30, 20, 12.5), _detection(60, 180, 20, 12, 0, 3.1)]
    elif where == "top-left corner":  # no room above or left of the target
        dets = [_detection(24, 18, 40, 30, 10, 12.5), _detection(70, 20, 30, 20, 0, 3.1)]
    else:  # the target walled in by other detections on three sides
        dets = [_detection(160, 120, 40, 30, 0, 12.5), _detection(160, 80, 60, 20, 0, 4.0),
                _detection(115, 120, 20, 60, 0, 3.0), _detection(205, 120, 20, 60, 0, 2.0)]
    result = DetectionResult(saliency=np.zeros((h, w), np.float32), detections=tuple(dets),
                             timestamp_ns=0, camera_id="wide", seq=0)
    kept = (132.0, 96.0, 188.0, 144.0) if where == "centre" else None
    out = draw_overlay(img, result, kept_box=kept)
    frame = out[:h, :w]
    # the map is zero (no colour), so inside a box only its own outline (2 px, anti-aliased)
    # may change a pixel: anything else there is a label
    for det in dets:
        inside = _interior((h, w), det.corners_px, erode_px=3)
        assert inside.sum() > 50
        changed = np.any(frame != img, axis=2) & inside
        assert not changed.any(), f"{changed.sum()} px of a box painted over ({where})"
    if kept is not None:
        u0, v0, u1, v1 = (int(round(c)) for c in kept)
        inside = np.zeros((h, w), bool)
        inside[v0 + 3:v1 - 2, u0 + 3:u1 - 2] = True
        inside &= ~_outline_band((h, w), dets[0].corners_px)
        assert not (np.any(frame != img, axis=2) & inside).any()
    # the labels were drawn (outside the boxes), and the legend lies below the frame
    outside = ~_outline_band((h, w), dets[0].corners_px, grow=True)
    for det in dets[1:]:
        outside &= ~_outline_band((h, w), det.corners_px, grow=True)
    assert (np.any(frame != img, axis=2) & outside).sum() > 200
    assert out.shape[0] > h and out.shape[1] == max(w, MIN_WIDTH_PX)


def _outline_band(shape, corners, grow=False):
    """The polygon's interior and its outline (grown 3 px when ``grow``)."""
    mask = np.zeros(shape, np.uint8)
    cv2.fillPoly(mask, [np.round(corners).astype(np.int32)], 255)
    cv2.polylines(mask, [np.round(corners).astype(np.int32)], True, 255, 3)
    if grow:
        mask = cv2.dilate(mask, np.ones((7, 7), np.uint8))
    return mask > 0


def test_colour_only_where_the_map_is_salient(rng):
    w, h = 200, 150
    img = _frame(rng, w, h)
    sal = np.full((h, w), 0.15, np.float32)  # below T/2 = 60/255 everywhere ...
    yy, xx = np.mgrid[0:h, 0:w]
    sal[(xx - 150) ** 2 + (yy - 100) ** 2 < 15 ** 2] = 0.9  # ... but a salient blob
    result = DetectionResult(saliency=sal, detections=(), timestamp_ns=0, camera_id="wide",
                             seq=0, threshold=120 / 255)
    frame = draw_overlay(img, result)[:h, :w]
    changed = np.any(frame != img, axis=2)
    blob = (xx - 150) ** 2 + (yy - 100) ** 2 < 12 ** 2
    far = (xx - 150) ** 2 + (yy - 100) ** 2 > 20 ** 2
    assert changed[blob].all()  # coloured
    assert not changed[far].any()  # the rest keeps the frame's own pixels


def test_narrow_grey_frame_is_padded_at_its_own_coordinates(rng):
    w, h = 96, 72
    grey = np.clip(rng.randn(h, w) * 10 + 100, 0, 255).astype(np.uint8)
    det = _detection(40, 30, 16, 12, 0, 5.0)
    result = DetectionResult(saliency=np.zeros((h, w), np.float32), detections=(det,),
                             timestamp_ns=0, camera_id="wide", seq=0)
    out = draw_overlay(grey, result)
    assert out.dtype == np.uint8 and out.ndim == 3 and out.shape[1] == MIN_WIDTH_PX
    # the MBR's outline is drawn where its corners are in the frame
    u, v = (int(round(c)) for c in det.corners_px[2])
    assert tuple(out[v, u]) != (grey[v, u],) * 3
    with pytest.raises(ValueError, match="does not match"):
        draw_overlay(grey, DetectionResult(saliency=np.zeros((h, w + 1), np.float32),
                                           detections=(), timestamp_ns=0, camera_id="wide",
                                           seq=0))


def test_threshold_on_the_0_255_scale():
    assert threshold_uint8(120 / 255) == 120 and threshold_uint8(1.5) == 255
    assert threshold_uint8(-1) == 0
