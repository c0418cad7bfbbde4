"""Where a detection's box is, on the plane of the target's top (pure functions).

A saliency detector's MBR bounds either the target's top face alone (a bright top over shaded
sides) or the whole box silhouette (top + the side faces the tilted camera sees), depending on
lighting, texture and heading. Measured against the synthetic world's truth (campaign seed 7,
wide camera, 1-13 m): run 0's detections were centred on the top face (within 2 px), run 1's
on the silhouette, 15-20 px apart at 2 m. A fixed intersection plane (the bearing estimator's
mid-height default) is then off by ``h / 2 / tan(depression)`` either way: 7-9 cm along the
line of sight at 1-2.5 m, the main horizontal error of the final approach.

:func:`fit_on_top_plane` therefore tests both region models over a grid of headings: for each,
it moves the target's top-face centre on its known plane until the projected region's MBR
centre lands on the detection's, and scores the model by how well the MBR's side lengths
match and its long side's direction; the best-scoring model gives the position. Camera pose = the vehicle's estimated pose
at the frame (the ground plane is at home's height, docs/conventions.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from eaglemission.geometry import CameraModel, Pose

REGIONS = ("top", "box")


@dataclass(frozen=True, slots=True)
class PlaneFit:
    """Result of :func:`fit_on_top_plane`: the top-face centre in NED, the region model that
    explained the detection, the heading tried, the MBR side-length mismatch (sum of |log
    ratio|) and the detection-to-model size ratio (> 1: the detection is larger)."""

    position_ned_m: tuple[float, float, float]
    region: str
    yaw_deg: float
    cost: float
    size_ratio: float


def box_points_ned(top_ned_m: Any, yaw_deg: float, length_m: float, width_m: float,
                   height_m: float, region: str) -> np.ndarray:
    """Corners of the top face (``region="top"``, 4) or of the whole box (``"box"``, 8)."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    hl, hw = length_m / 2, width_m / 2
    top = [(top_ned_m[0] + c * x - s * y, top_ned_m[1] + s * x + c * y, top_ned_m[2])
           for x, y in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))]
    if region == "top":
        return np.asarray(top)
    return np.asarray(top + [(n, e, d + height_m) for n, e, d in top])


def mbr(points_px: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre, sorted side lengths and the long side's direction (deg, modulo 180) of the
    minimum-area rectangle of image points."""
    (cx, cy), (w, h), ang = cv2.minAreaRect(np.asarray(points_px, dtype=np.float32))
    long_deg = float(ang if w >= h else ang + 90.0) % 180.0
    return np.array([cx, cy]), np.sort(np.array([w, h], dtype=np.float64)), long_deg


def angle_cost(dims_a: np.ndarray, long_a_deg: float, dims_b: np.ndarray,
               long_b_deg: float, per_deg: float = 1.0 / 45.0) -> float:
    """Mismatch of two rectangles' long-side directions, weighted by how elongated both are
    (the direction of a square is undefined)."""
    d = abs((long_a_deg - long_b_deg + 90.0) % 180.0 - 90.0)
    elong = min(dims_a[1] / max(dims_a[0], 1e-9), dims_b[1] / max(dims_b[0], 1e-9)) - 1.0
    return d * per_deg * float(np.clip(elong / 0.3, 0.0, 1.0))


def plane_hit(cam_ned: Pose, model: CameraModel, pixel: Any, plane_down_m: float
              ) -> np.ndarray | None:
    """Where the ray through ``pixel`` meets the plane ``down = plane_down_m`` (NED)."""
    ray = cam_ned.R @ model.rays_optical(np.asarray([pixel], dtype=np.float64))[0]
    drop = plane_down_m - float(cam_ned.t[2])
    if ray[2] <= 1e-3 or drop <= 0:
        return None
    return np.asarray(cam_ned.t + ray * (drop / float(ray[2])))


def clip_to_image(points_px: np.ndarray, width_px: int, height_px: int) -> np.ndarray | None:
    """The convex hull of image points clipped to the image rectangle (what a detector can
    see of a target at the border); None when nothing is left."""
    hull = cv2.convexHull(np.asarray(points_px, dtype=np.float32))
    rect = np.array([[0, 0], [width_px - 1, 0], [width_px - 1, height_px - 1],
                     [0, height_px - 1]], dtype=np.float32)
    area, poly = cv2.intersectConvexConvex(hull, rect)
    if poly is None or area <= 1.0:
        return None
    return np.asarray(poly, dtype=np.float64).reshape(-1, 2)


def fit_on_top_plane(model: CameraModel, cam_ned: Pose, center_px: Any, corners_px: Any,
                     target: Any, *, ground_down_m: float = 0.0, yaw_step_deg: float = 15.0,
                     iterations: int = 3, yaw_hint_deg: float | None = None,
                     region_hint: str | None = None) -> PlaneFit | None:
    """Top-face centre of the target whose top face or box silhouette best explains a
    detection (see the module docstring); None when the ray misses the plane or the model
    does not project in front of the camera.

    The projected model is clipped to the image like the detection, so a target cut by the
    image border (the final metres of the approach) still fits; ``yaw_hint_deg`` /
    ``region_hint`` (from earlier, complete views) restrict the headings to +-``yaw_step_deg``
    (7 headings) and the region model, since a cut view constrains them poorly."""
    plane = ground_down_m - float(target.height_m)
    to_cam = cam_ned.inverse()
    # the detection's MBR may reach past the border: compare what lies inside the image
    seen_det = clip_to_image(np.asarray(corners_px, dtype=np.float64), model.width_px,
                             model.height_px)
    if seen_det is None:
        return None
    c_det, dims_det, long_det = mbr(seen_det)
    if not (dims_det > 0).all():
        return None
    best: PlaneFit | None = None
    # a box is symmetric under a half turn: headings over 180 deg suffice
    yaws = (np.arange(0.0, 180.0, yaw_step_deg) if yaw_hint_deg is None
            else yaw_hint_deg + np.linspace(-yaw_step_deg, yaw_step_deg, 7))
    regions = REGIONS if region_hint is None else (region_hint,)
    for yaw in yaws:
        for region in regions:
            pix = c_det
            p = plane_hit(cam_ned, model, pix, plane)
            if p is None:
                return None
            dims, long_model = None, 0.0
            for _ in range(iterations):
                pts = box_points_ned(p, float(yaw), target.length_m, target.width_m,
                                     target.height_m, region)
                px = model.project(to_cam.apply(np.vstack([pts, p[None, :]])))
                if not np.isfinite(px).all():
                    dims = None
                    break
                seen = clip_to_image(px[:-1], model.width_px, model.height_px)
                if seen is None:
                    dims = None
                    break
                c_model, dims, long_model = mbr(seen)
                # shift the ray by the model's MBR-centre offset from the top-face centre
                pix = c_det - (c_model - px[-1])
                q = plane_hit(cam_ned, model, pix, plane)
                if q is None:
                    dims = None
                    break
                p = q
            if dims is None or not (dims > 0).all():
                continue
            ratio = dims_det / dims
            cost = float(np.abs(np.log(ratio)).sum()) + angle_cost(dims_det, long_det, dims,
                                                                   long_model)
            if best is None or cost < best.cost:
                best = PlaneFit((float(p[0]), float(p[1]), float(p[2])), region,
                                float(yaw) % 180.0, cost, float(np.sqrt(ratio.prod())))
    return best


def colour_blob(image_bgr: np.ndarray, target_bgr: Any, tolerance: float, near_px: Any, *,
                min_area_px: float = 200.0, step: int = 2, min_brightness: float = 60.0,
                camera_id: str = "") -> Any:
    """Close-range fallback detection (not in the paper): the connected region of the target's
    chromaticity nearest ``near_px``, as a :class:`~eaglemission.types.Detection` (its MBR).

    At a metre the target fills a tenth of the wide image and a rarity-based saliency map
    (DTDMI's ``field`` preset) stops singling it out; its colour still does. The top and the
    shaded side faces share the chromaticity, so the region is the box silhouette (cut by the
    image border near the grasp pose). Works on every ``step``-th pixel; None when no region of
    at least ``min_area_px`` (full-resolution pixels) is found."""
    from eaglemission.detectors.regions import order_corners

    from eaglemission.types import Detection

    img = np.asarray(image_bgr)
    if img.ndim != 3:
        return None
    small = np.ascontiguousarray(img[::step, ::step])
    t = np.asarray(target_bgr, dtype=np.float32)
    t = t / max(1.0, float(t.sum()))
    # Per-channel float32 planes: the same arithmetic as an (H, W, 3) chromaticity, ~5x faster.
    b, g, r = (p.astype(np.float32) for p in cv2.split(small))
    total = (b + g) + r
    den = np.maximum(total, np.float32(1.0))
    dist = np.abs(b / den - t[0])
    dist += np.abs(g / den - t[1])
    dist += np.abs(r / den - t[2])
    mask = ((dist <= tolerance) & (total >= min_brightness)).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
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
    ys, xs = np.nonzero(labels == best)
    pts = (np.stack([xs, ys], axis=1).astype(np.float32) + 0.5) * step - 0.5
    (cx, cy), (w, h), ang = cv2.minAreaRect(pts)
    corners = order_corners(cv2.boxPoints(((cx, cy), (w, h), ang)).astype(np.float64))
    long_, short = (w, h) if w >= h else (h, w)
    return Detection(score=1.0, center_px=(float(cx), float(cy)), corners_px=corners,
                     size_px=(float(long_), float(short)), angle_deg=float(ang),
                     area_px=float(len(xs) * step * step), camera_id=camera_id)
