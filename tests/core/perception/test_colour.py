"""The target's colour region and colour check (eaglemission/perception/colour.py), through
:class:`~eaglemission.perception.appearance.TargetAppearance`."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from eaglemission.config import TargetConfig
from eaglemission.perception.appearance import TargetAppearance
from eaglemission.perception.colour import (
    _components,
    colour_blob,
    colour_mask_numpy,
)
from eaglemission.types import Frame


def test_without_a_target_colour_there_is_no_region_and_nothing_to_check() -> None:
    t = TargetAppearance.of_target(TargetConfig(length_m=0.4, width_m=0.25))
    assert not t.has_colour and not t.has_model and not t.known
    img = np.zeros((40, 40, 3), np.uint8)
    assert t.colour_region(Frame(img, 1, "wide", 1), (20.0, 20.0)) is None


def test_the_colour_region_is_found_and_matches_the_target_colour() -> None:
    img = np.full((240, 320, 3), (40, 140, 60), np.uint8)  # grass
    cv2.rectangle(img, (150, 100), (190, 130), (30, 40, 210), -1)  # the red box
    t = TargetAppearance.of_target(TargetConfig(length_m=0.4, width_m=0.25,
                                                color_bgr=(30, 40, 210)))
    assert t.has_colour and not t.has_model
    frame = Frame(img, 1, "narrow", 1)
    det = t.colour_region(frame, (170.0, 115.0))
    assert det is not None and det.camera_id == "narrow"
    assert abs(det.center_px[0] - 170) < 2 and abs(det.center_px[1] - 115) < 2
    assert t.colour_matches(frame, det)
    other = TargetAppearance(colour_bgr=(200, 40, 30))
    assert not other.colour_matches(frame, det)


def test_colour_blob_finds_the_target_colour_near_the_prediction() -> None:
    rng = np.random.RandomState(3)
    img = np.clip(rng.normal((60, 120, 70), 12, (480, 640, 3)), 0, 255).astype(np.uint8)
    red = (30, 40, 210)
    cv2.fillPoly(img, [np.array([[300, 200], [420, 230], [400, 300], [280, 270]])], red)
    cv2.fillPoly(img, [np.array([[30, 30], [80, 30], [80, 60], [30, 60]])],
                 (15, 20, 105))  # same chromaticity, darker, far from the prediction
    det = colour_blob(img, red, 0.25, (350, 250))
    assert det is not None
    assert math.dist(det.center_px, (350, 250)) < 8
    assert det.area_px == pytest.approx(cv2.contourArea(np.array(
        [[300, 200], [420, 230], [400, 300], [280, 270]], np.float32)), rel=0.15)
    assert colour_blob(img, (200, 40, 30), 0.25, (350, 250)) is None  # no blue region
    # the region's outline (convex hull) is the quadrilateral, not its bounding rectangle
    quad = np.array([[300, 200], [420, 230], [400, 300], [280, 270]], np.float32)
    assert det.hull_px is not None
    inter, _ = cv2.intersectConvexConvex(det.hull_px.astype(np.float32), quad)
    assert inter / cv2.contourArea(quad) > 0.93
    assert cv2.contourArea(det.hull_px.astype(np.float32)) < 1.07 * cv2.contourArea(quad)


def _colour_blob_reference(img, target_bgr, tolerance, near_px, min_area_px=200.0, step=2,
                           min_brightness=60.0):
    """The colour region's rectangle from ALL its pixels (colour_blob uses the boundary)."""
    t = np.asarray(target_bgr, dtype=np.float32)
    t = t / max(1.0, float(t.sum()))
    mask = colour_mask_numpy(img, step, t, tolerance, min_brightness)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    near = np.asarray(near_px, dtype=np.float64) / step
    ok = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] * step * step >= min_area_px]
    if not ok:
        return None
    best = min(ok, key=lambda i: float(np.hypot(*(cents[i] - near))))
    ys, xs = np.nonzero(labels == best)
    pts = (np.stack([xs, ys], axis=1).astype(np.float32) + 0.5) * step - 0.5
    return cv2.minAreaRect(pts), float(len(xs) * step * step)


def test_colour_blob_kernel_and_boundary_rectangle_equal_the_references() -> None:
    """The compiled mask equals the numpy one bit for bit, and the rectangle from the region's
    boundary pixels equals the one from all its pixels, on random scenes and parameters."""
    from eaglemission.perception._colour_kernel import colour_mask

    rng = np.random.RandomState(11)
    found = 0
    for _ in range(80):
        h, w = rng.randint(40, 320, 2)
        img = rng.randint(0, 256, (h, w, 3)).astype(np.uint8)
        for _ in range(rng.randint(1, 5)):
            poly = np.column_stack((rng.randint(0, w, 5), rng.randint(0, h, 5)))
            cv2.fillPoly(img, [poly], tuple(int(v) for v in rng.randint(0, 256, 3)))
        target = tuple(int(v) for v in rng.randint(0, 256, 3))
        if rng.rand() < 0.5:  # a region of (a shade of) the target's colour
            poly = np.column_stack((rng.randint(0, w, 4), rng.randint(0, h, 4)))
            k = rng.uniform(0.4, 1.0)
            cv2.fillPoly(img, [poly], tuple(int(v * k) for v in target))
        tol, step = float(rng.uniform(0.02, 0.4)), int(rng.choice([1, 2, 3]))
        t = np.asarray(target, np.float32)
        t = t / max(1.0, float(t.sum()))
        assert np.array_equal(colour_mask(img, step, t, np.float32(tol), np.float32(60.0)),
                              colour_mask_numpy(img, step, t, tol, 60.0))
        near = (float(rng.uniform(0, w)), float(rng.uniform(0, h)))
        det = colour_blob(img, target, tol, near, min_area_px=30.0, step=step)
        ref = _colour_blob_reference(img, target, tol, near, min_area_px=30.0, step=step)
        assert (det is None) == (ref is None)
        if ref is None:
            continue
        found += 1
        (cx, cy), (rw, rh), ang = ref[0]
        assert det.center_px == (cx, cy) and det.angle_deg == ang
        assert det.size_px == (max(rw, rh), min(rw, rh)) and det.area_px == ref[1]
        numpy_det = colour_blob(img, target, tol, near, min_area_px=30.0, step=step,
                                backend="numpy")
        assert np.array_equal(numpy_det.corners_px, det.corners_px)
    assert found >= 30


def test_components_in_the_mask_box_equal_the_full_frame_call() -> None:
    """Stats and centroids (bit for bit) and each component's pixels, against
    cv2.connectedComponentsWithStats on the whole mask."""
    rng = np.random.RandomState(23)
    for _ in range(60):
        mask = np.zeros((rng.randint(20, 500), rng.randint(20, 700)), np.uint8)
        h, w = mask.shape
        for _ in range(rng.randint(0, 6)):
            poly = np.column_stack((rng.randint(0, w, 4), rng.randint(0, h, 4)))
            cv2.fillPoly(mask, [poly], 1)
        mask |= (rng.rand(h, w) < 0.002).astype(np.uint8)
        n, labels, (bx, by), stats, cents = _components(mask)
        n_ref, labels_ref, stats_ref, cents_ref = cv2.connectedComponentsWithStats(mask, connectivity=8)
        assert n == n_ref
        key = np.lexsort((stats[1:, 1], stats[1:, 0], stats[1:, 4]))
        key_ref = np.lexsort((stats_ref[1:, 1], stats_ref[1:, 0], stats_ref[1:, 4]))
        assert np.array_equal(stats[1:][key], stats_ref[1:][key_ref])
        assert np.array_equal(cents[1:][key], cents_ref[1:][key_ref])
        for i, j in zip(key[:5] + 1, key_ref[:5] + 1):
            full = np.zeros_like(mask, dtype=bool)
            full[by:by + labels.shape[0], bx:bx + labels.shape[1]] = labels == i
            assert np.array_equal(full, labels_ref == j)
