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
from eaglemission.kernels import lazy_kernel

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


def _image_rect(width_px: int, height_px: int) -> np.ndarray:
    return np.array([[0, 0], [width_px - 1, 0], [width_px - 1, height_px - 1],
                     [0, height_px - 1]], dtype=np.float32)


def _clipped_mbr(points_px: np.ndarray, image_rect: np.ndarray) -> Any:
    """``cv2.minAreaRect`` of ``clip_to_image(points_px)`` (float32 points; None when the
    clipped region is empty), as :func:`mbr` computes it."""
    hull = cv2.convexHull(points_px)
    area, poly = cv2.intersectConvexConvex(hull, image_rect)
    if poly is None or area <= 1.0:
        return None
    return cv2.minAreaRect(poly)


def clip_to_image(points_px: np.ndarray, width_px: int, height_px: int) -> np.ndarray | None:
    """The convex hull of image points clipped to the image rectangle (what a detector can
    see of a target at the border); None when nothing is left."""
    hull = cv2.convexHull(np.asarray(points_px, dtype=np.float32))
    area, poly = cv2.intersectConvexConvex(hull, _image_rect(width_px, height_px))
    if poly is None or area <= 1.0:
        return None
    return np.asarray(poly, dtype=np.float64).reshape(-1, 2)


def angle_costs(dims_a: np.ndarray, long_a_deg: float, dims_b: np.ndarray,
                long_b_deg: np.ndarray, per_deg: float = 1.0 / 45.0) -> np.ndarray:
    """:func:`angle_cost` of one rectangle against (n,) rectangles (``dims_b`` (n, 2))."""
    d = np.abs((long_a_deg - long_b_deg + 90.0) % 180.0 - 90.0)
    elong_b = dims_b[:, 1] / np.maximum(dims_b[:, 0], 1e-9)
    elong = np.minimum(dims_a[1] / max(dims_a[0], 1e-9), elong_b) - 1.0
    return d * per_deg * np.clip(elong / 0.3, 0.0, 1.0)


def plane_hits(cam_ned: Pose, model: CameraModel, pixels: Any, plane_down_m: float
               ) -> np.ndarray:
    """:func:`plane_hit` of (n, 2) pixels: (n, 3), NaN rows where the ray misses."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    out = np.full((len(px), 3), np.nan)
    drop = plane_down_m - float(cam_ned.t[2])
    if len(px) == 0 or drop <= 0:
        return out
    # R @ ray per row (a stacked matrix-vector product: the same rounding as plane_hit's)
    rays = (cam_ned.R[None] @ model.rays_optical(px)[:, :, None])[:, :, 0]
    ok = rays[:, 2] > 1e-3
    out[ok] = cam_ned.t + rays[ok] * (drop / rays[ok, 2:3])
    return out


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
    (7 headings) and the region model, since a cut view constrains them poorly.

    All (heading, region) hypotheses are iterated together: projections and ray-plane
    intersections are batched, only the clipping and the MBR (OpenCV) run per hypothesis.
    Same fits as :func:`fit_on_top_plane_reference` (tests/missions/test_silhouette.py)."""
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
    # a box is symmetric under a half turn: headings over 180 deg suffice
    yaws = (np.arange(0.0, 180.0, yaw_step_deg) if yaw_hint_deg is None
            else yaw_hint_deg + np.linspace(-yaw_step_deg, yaw_step_deg, 7))
    regions = REGIONS if region_hint is None else (region_hint,)
    hyps = [(float(yaw), region) for yaw in yaws for region in regions]
    if not hyps:
        return None
    p0 = plane_hit(cam_ned, model, c_det, plane)
    if p0 is None:
        return None
    n = len(hyps)
    n_pts = np.array([4 if r == "top" else 8 for _, r in hyps])
    cs = np.array([(math.cos(math.radians(y)), math.sin(math.radians(y))) for y, _ in hyps])
    hl, hw = target.length_m / 2, target.width_m / 2
    x = np.array([hl, hl, -hl, -hl])
    y = np.array([-hw, hw, hw, -hw])
    cx, sy = cs[:, :1] * x, cs[:, 1:] * y  # (n, 4), as box_points_ned
    sx, cy = cs[:, 1:] * x, cs[:, :1] * y
    p = np.repeat(p0[None, :], n, axis=0)
    dims = np.zeros((n, 2))
    long_model = np.zeros(n)
    alive = np.ones(n, dtype=bool)
    pts = np.empty((n, 9, 3))
    image_rect = _image_rect(model.width_px, model.height_px)
    for _ in range(iterations):
        idx = np.flatnonzero(alive)
        if len(idx) == 0:
            break
        q = p[idx]
        k = len(idx)
        pts_k = pts[:k]
        pts_k[:, :4, 0] = q[:, :1] + cx[idx] - sy[idx]
        pts_k[:, :4, 1] = q[:, 1:2] + sx[idx] + cy[idx]
        pts_k[:, :4, 2] = q[:, 2:3]
        pts_k[:, 4:8, :2] = pts_k[:, :4, :2]
        pts_k[:, 4:8, 2] = q[:, 2:3] + target.height_m
        pts_k[:, 8] = q
        px = model.project(to_cam.apply(pts_k.reshape(-1, 3))).reshape(k, 9, 2)
        fin = np.isfinite(px).all(axis=2)
        fin = fin[:, 8] & fin[:, :4].all(axis=1) & ((n_pts[idx] == 4) | fin[:, 4:8].all(axis=1))
        px32 = px.astype(np.float32)  # what OpenCV sees (clip_to_image, mbr)
        c_model = np.zeros((k, 2))
        for j, h in enumerate(idx):
            rect = _clipped_mbr(px32[j, :n_pts[h]], image_rect) if fin[j] else None
            if rect is None:
                alive[h] = False
                continue
            (c_model[j, 0], c_model[j, 1]), (w, ht), ang = rect
            dims[h] = (w, ht) if w <= ht else (ht, w)
            long_model[h] = float(ang if w >= ht else ang + 90.0) % 180.0
        # shift the ray by the model's MBR-centre offset from the top-face centre
        pix = c_det - (c_model - px[:, 8])
        keep = alive[idx]
        hits = plane_hits(cam_ned, model, pix[keep], plane)
        ok = np.isfinite(hits).all(axis=1)
        alive[idx[keep][~ok]] = False
        p[idx[keep][ok]] = hits[ok]
    valid = alive & (dims > 0).all(axis=1) if iterations > 0 else np.zeros(n, dtype=bool)
    if not valid.any():
        return None
    ratio = dims_det / np.where(valid[:, None], dims, 1.0)
    cost = np.abs(np.log(ratio)).sum(axis=1) + angle_costs(dims_det, long_det, dims, long_model)
    best = int(np.flatnonzero(valid)[np.argmin(cost[valid])])
    pb = p[best]
    return PlaneFit((float(pb[0]), float(pb[1]), float(pb[2])), hyps[best][1],
                    hyps[best][0] % 180.0, float(cost[best]),
                    float(np.sqrt(ratio[best].prod())))


def fit_on_top_plane_reference(model: CameraModel, cam_ned: Pose, center_px: Any, corners_px: Any,
                     target: Any, *, ground_down_m: float = 0.0, yaw_step_deg: float = 15.0,
                     iterations: int = 3, yaw_hint_deg: float | None = None,
                     region_hint: str | None = None) -> PlaneFit | None:
    """The straightforward implementation of :func:`fit_on_top_plane` (one hypothesis at a
    time), kept as the reference its tests compare the batched path against."""
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
    return ((dist <= tolerance) & (total >= min_brightness)).astype(np.uint8)


# the compiled colour mask (loaded on first use; None: colour_mask_numpy)
_colour_kernel = lazy_kernel("eaglemission.missions._colour_kernel", "colour_mask")


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
    from eaglemission.detectors.regions import order_corners

    from eaglemission.types import Detection

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
                     camera_id=camera_id)
