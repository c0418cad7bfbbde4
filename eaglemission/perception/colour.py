"""The target found by its colour (not in the paper): the colour part of
:class:`~eaglemission.perception.appearance.TargetAppearance`.

At a metre the target fills a tenth of the wide image and a rarity-based saliency map (DTDMI's
``field`` preset) stops singling it out; its colour still does. :func:`colour_blob` returns the
connected region of the target's chromaticity nearest a predicted pixel; :func:`colour_matches`
checks that a detector's region has the target's chromaticity. Both need
``target.color_bgr``.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from eaglemission.geometry import order_corners
from eaglemission.kernels import lazy_kernel
from eaglemission.perception.regions import outline_hull
from eaglemission.types import Detection


def chromaticity(bgr: Any) -> np.ndarray:
    """(b, g, r) / (b + g + r): colour without brightness (lighting gain, shading)."""
    c = np.asarray(bgr, dtype=np.float64)
    return c / max(1.0, float(c.sum()))


def colour_matches(image: np.ndarray, det: Detection, target_bgr: Any, tolerance: float) -> bool:
    """The median colour of the detection's core (its MBR shrunk to half size) has the target's
    chromaticity within ``tolerance`` (L1)."""
    if image.ndim != 3:
        return True
    c = np.asarray(det.corners_px, dtype=np.float64)
    core = c.mean(axis=0) + 0.5 * (c - c.mean(axis=0))
    x0, y0 = np.floor(core.min(axis=0)).astype(int)
    x1, y1 = np.ceil(core.max(axis=0)).astype(int) + 1
    h, w = image.shape[:2]
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
    if x1 <= x0 or y1 <= y0:
        return False
    patch = image[y0:y1, x0:x1].reshape(-1, 3)
    if len(patch) > 4096:
        patch = patch[:: len(patch) // 4096]
    med = np.median(patch, axis=0)
    return float(np.abs(chromaticity(med) - chromaticity(target_bgr)).sum()) <= tolerance


def colour_mask_numpy(image_bgr: np.ndarray, step: int, target_chroma: np.ndarray,
                      tolerance: float, min_brightness: float) -> np.ndarray:
    """uint8 mask of ``image_bgr[::step, ::step]``: chromaticity within ``tolerance`` (L1) of
    ``target_chroma`` (float32, sums to 1) and B + G + R >= ``min_brightness`` (the
    reference of the compiled ``_colour_kernel.colour_mask``)."""
    small = np.ascontiguousarray(image_bgr[::step, ::step])
    t = np.asarray(target_chroma, dtype=np.float32)
    # Per-channel float32 planes: the same arithmetic as an (H, W, 3) chromaticity, ~5x faster.
    b, g, r = (p.astype(np.float32) for p in cv2.split(small))
    total = (b + g) + r
    den = np.maximum(total, np.float32(1.0))
    dist = np.abs(b / den - t[0])
    dist += np.abs(g / den - t[1])
    dist += np.abs(r / den - t[2])
    mask: np.ndarray = ((dist <= tolerance) & (total >= min_brightness)).astype(np.uint8)
    return mask


# the compiled colour mask (loaded on first use; None: colour_mask_numpy)
_colour_kernel = lazy_kernel("eaglemission.perception._colour_kernel", "colour_mask")


def _components(mask: np.ndarray) -> tuple[int, np.ndarray, tuple[int, int], np.ndarray,
                                          np.ndarray]:
    """``cv2.connectedComponentsWithStats(mask, connectivity=8)`` computed on the bounding box
    of the mask's pixels (~1/8 of the frame near the target: several times faster).

    Returns (n, labels of the box, the box's (left, top), stats, centroids), stats and
    centroids in full-image coordinates; the centroids are rebuilt from OpenCV's integer
    coordinate sums and divided as OpenCV divides them (the same doubles as a full-frame call).
    """
    x0, y0, w, h = cv2.boundingRect(mask)
    if w == 0 or h == 0:
        return 1, np.zeros((0, 0), np.int32), (0, 0), np.zeros((1, 5), np.int32), np.zeros((1, 2))
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask[y0:y0 + h, x0:x0 + w],
                                                               connectivity=8)
    area = stats[:, cv2.CC_STAT_AREA].astype(np.float64)[:, None]
    sums = np.rint(cents * area) + np.array([x0, y0]) * area  # exact integers (< 2**53)
    cents = sums / np.maximum(area, 1.0)
    stats = stats.copy()
    stats[:, cv2.CC_STAT_LEFT] += x0
    stats[:, cv2.CC_STAT_TOP] += y0
    return n, labels, (x0, y0), stats, cents


def colour_blob(image_bgr: np.ndarray, target_bgr: Any, tolerance: float, near_px: Any, *,
                min_area_px: float = 200.0, step: int = 2, min_brightness: float = 60.0,
                camera_id: str = "", backend: str = "numba") -> Any:
    """Close-range fallback detection (not in the paper): the connected region of the target's
    chromaticity nearest ``near_px``, as a :class:`~eaglemission.types.Detection` (its MBR).

    At a metre the target fills a tenth of the wide image and a rarity-based saliency map
    (DTDMI's ``field`` preset) stops singling it out; its colour still does. The top and the
    shaded side faces share the chromaticity, so the region is the box silhouette (cut by the
    image border near the grasp pose). Works on every ``step``-th pixel; None when no region of
    at least ``min_area_px`` (full-resolution pixels) is found. ``backend="numpy"`` computes
    the colour mask without numba (same mask)."""
    img = np.asarray(image_bgr)
    if img.ndim != 3:
        return None
    t = np.asarray(target_bgr, dtype=np.float32)
    t = t / max(1.0, float(t.sum()))
    # Python floats: numpy compares them with float32 arrays in float32, as the kernel does
    tolerance, min_brightness = float(tolerance), float(min_brightness)
    kern = _colour_kernel() if backend == "numba" and img.dtype == np.uint8 else None
    if kern is not None:
        mask = kern(np.ascontiguousarray(img), int(step), t, np.float32(tolerance),
                    np.float32(min_brightness))
    else:
        mask = colour_mask_numpy(img, step, t, tolerance, min_brightness)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, (bx, by), stats, cents = _components(mask)
    if n <= 1:
        return None
    near = np.asarray(near_px, dtype=np.float64) / step
    best, best_d = -1, math.inf
    for i in range(1, n):
        if stats[i, cv2.CC_STAT_AREA] * step * step < min_area_px:
            continue
        d = float(np.hypot(*(cents[i] - near)))
        if d < best_d:
            best, best_d = i, d
    if best < 0:
        return None
    # The region's MBR is that of its convex hull, whose vertices lie on its outer boundary:
    # the boundary pixels give the same rectangle as all pixels, far faster.
    x0, y0, w0, h0 = (int(v) for v in stats[best, :4])
    region = (labels[y0 - by:y0 - by + h0, x0 - bx:x0 - bx + w0] == best).astype(np.uint8)
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE,
                                   offset=(x0, y0))
    edge = np.concatenate([c.reshape(-1, 2) for c in contours])
    pts = (edge.astype(np.float32) + 0.5) * step - 0.5
    (cx, cy), (w, h), ang = cv2.minAreaRect(pts)
    corners = order_corners(cv2.boxPoints(((cx, cy), (w, h), ang)).astype(np.float64))
    long_, short = (w, h) if w >= h else (h, w)
    return Detection(score=1.0, center_px=(float(cx), float(cy)), corners_px=corners,
                     size_px=(float(long_), float(short)), angle_deg=float(ang),
                     area_px=float(stats[best, cv2.CC_STAT_AREA] * step * step),
                     camera_id=camera_id, hull_px=outline_hull(pts, step / 2.0))


def warm_up_colour_kernel() -> None:
    """Compile (or load from numba's cache) the colour mask's kernel now."""
    colour_blob(np.zeros((8, 8, 3), np.uint8), (1, 1, 1), 0.1, (0, 0))
