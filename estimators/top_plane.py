"""Plugin ``top_plane`` (role ``fitters``): where a detection's box is, on the plane of the
target's top.

A saliency detector's MBR bounds either the target's top face alone (a bright top over shaded
sides) or the whole box silhouette (top + the side faces the tilted camera sees), depending on
lighting, texture and heading. Measured against the synthetic world's truth (the first two
worlds of ``eaglemission campaign --seed 7``, wide camera, 1-13 m): the first world's detections
were centred on the top face (within 2 px), the second's on the silhouette, 15-20 px apart at
2 m. A fixed intersection plane (the bearing estimator's
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
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, ClassVar

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.geometry import CameraModel, Pose, ray_plane_points
from eaglemission.interfaces.estimator import CameraView
from eaglemission.kernels import lazy_kernel
from eaglemission.types import Detection, PlaneFit

if TYPE_CHECKING:
    from eaglemission.config import TargetConfig

REGIONS = ("top", "box")


def box_points_ned(top_ned_m: Sequence[float] | NDArray[np.float64], yaw_deg: float,
                   length_m: float, width_m: float, height_m: float, region: str
                   ) -> NDArray[np.float64]:
    """Corners of the top face (``region="top"``, 4) or of the whole box (``"box"``, 8)."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    hl, hw = length_m / 2, width_m / 2
    top = [(top_ned_m[0] + c * x - s * y, top_ned_m[1] + s * x + c * y, top_ned_m[2])
           for x, y in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))]
    if region == "top":
        return np.asarray(top)
    return np.asarray(top + [(n, e, d + height_m) for n, e, d in top])


def mbr(points_px: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Centre, sorted side lengths and the long side's direction (deg, modulo 180) of the
    minimum-area rectangle of image points."""
    return rect_fields(cv2.minAreaRect(np.asarray(points_px, dtype=np.float32)))


def rect_fields(rect: cv2.typing.RotatedRect
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """An OpenCV rotated rectangle as :func:`mbr` gives it."""
    (cx, cy), (w, h), ang = rect
    long_deg = float(ang if w >= h else ang + 90.0) % 180.0
    return np.array([cx, cy]), np.sort(np.array([w, h], dtype=np.float64)), long_deg


def angle_cost(dims_a: NDArray[np.float64], long_a_deg: float, dims_b: NDArray[np.float64],
               long_b_deg: float, per_deg: float = 1.0 / 45.0) -> float:
    """Mismatch of two rectangles' long-side directions, weighted by how elongated both are
    (the direction of a square is undefined)."""
    d = abs((long_a_deg - long_b_deg + 90.0) % 180.0 - 90.0)
    elong = min(dims_a[1] / max(dims_a[0], 1e-9), dims_b[1] / max(dims_b[0], 1e-9)) - 1.0
    return d * per_deg * float(np.clip(elong / 0.3, 0.0, 1.0))


def plane_hit(cam_ned: Pose, model: CameraModel, pixel: ArrayLike, plane_down_m: float
              ) -> NDArray[np.float64] | None:
    """Where the ray through ``pixel`` meets the plane ``down = plane_down_m`` (NED)."""
    ray = cam_ned.R @ model.rays_optical(np.asarray([pixel], dtype=np.float64))[0]
    hit = ray_plane_points(tuple(cam_ned.t), ray[None, :], plane_down_m, min_down=1e-3)[0]
    return hit if np.isfinite(hit).all() else None


def _image_rect(width_px: int, height_px: int) -> NDArray[np.float32]:
    return np.array([[0, 0], [width_px - 1, 0], [width_px - 1, height_px - 1],
                     [0, height_px - 1]], dtype=np.float32)


def _clipped_mbr(points_px: NDArray[np.float32], image_rect: NDArray[np.float32],
                 occluder_px: NDArray[np.float32] | None = None
                 ) -> cv2.typing.RotatedRect | None:
    """``cv2.minAreaRect`` of ``clip_to_image(points_px)`` (float32 points; None when the
    clipped region is empty), as :func:`mbr` computes it; with ``occluder_px``, of what the
    occluder leaves of it (:func:`visible_mbr`)."""
    hull = cv2.convexHull(points_px)
    area, poly = cv2.intersectConvexConvex(hull, image_rect)
    if poly is None or area <= 1.0:
        return None
    if occluder_px is not None:
        return visible_mbr(np.asarray(poly, dtype=np.float32).reshape(-1, 2), occluder_px)
    return cv2.minAreaRect(poly)


_visible_kernel = lazy_kernel("eaglemission.estimators._occlusion_kernel", "visible_points")


def _edge_crossings(a_px: NDArray[np.float64], b_px: NDArray[np.float64]
                    ) -> NDArray[np.float64]:
    """(k, 2) points where an edge of closed polygon ``a`` crosses an edge of ``b``."""
    p, r = a_px, np.concatenate((a_px[1:], a_px[:1])) - a_px  # edges p + t r, t in [0, 1]
    q, s = b_px, np.concatenate((b_px[1:], b_px[:1])) - b_px
    qx = q[None, :, 0] - p[:, None, 0]  # (n, m)
    qy = q[None, :, 1] - p[:, None, 1]
    rxs = np.outer(r[:, 0], s[:, 1]) - np.outer(r[:, 1], s[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qx * s[:, 1] - qy * s[:, 0]) / rxs
        u = (qx * r[:, 1:2] - qy * r[:, 0:1]) / rxs
    hit = (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)  # parallel edges: t, u not finite
    i = np.nonzero(hit)[0]
    crossings: NDArray[np.float64] = p[i] + t[hit][:, None] * r[i]
    return crossings


def visible_mbr(region_px: NDArray[np.float32], occluder_px: NDArray[np.float32]
                ) -> cv2.typing.RotatedRect | None:
    """``cv2.minAreaRect`` of the part of a convex region (float32 (n, 2)) that a convex
    occluder nearer the camera leaves visible (the arm's tool over the target: a detector's
    region stops at the tool, not at the target's hidden edge); None when nothing is left.

    The part left is not convex, but its rectangle is its convex hull's, and the hull's corners
    are the region's corners outside the occluder and the points where the two outlines cross
    (the occluder's own corners make dents, never hull corners)."""
    region = np.asarray(region_px, dtype=np.float64).reshape(-1, 2)
    occ = np.asarray(occluder_px, dtype=np.float64).reshape(-1, 2)
    if ((region.max(axis=0) <= occ.min(axis=0)).any()
            or (occ.max(axis=0) <= region.min(axis=0)).any()):
        return cv2.minAreaRect(region.astype(np.float32))  # apart
    kernel = _visible_kernel()
    pts = (visible_points_numpy(region, occ) if kernel is None
           else kernel(region, occ)).astype(np.float32)
    if len(pts) < 3 or cv2.contourArea(cv2.convexHull(pts)) <= 1.0:
        return None
    return cv2.minAreaRect(pts)


def visible_points_numpy(region: NDArray[np.float64], occ: NDArray[np.float64]
                         ) -> NDArray[np.float64]:
    """The corners :func:`visible_mbr` measures (the compiled kernel's reference): the
    region's corners not strictly inside the convex occluder (on the same side of all its
    edges) and the points where the outlines cross."""
    edge = np.concatenate((occ[1:], occ[:1])) - occ
    rel = region[:, None, :] - occ[None, :, :]
    cross = edge[None, :, 0] * rel[..., 1] - edge[None, :, 1] * rel[..., 0]
    inside = (cross > 0).all(axis=1) | (cross < 0).all(axis=1)
    pts: NDArray[np.float64] = np.vstack([region[~inside], _edge_crossings(region, occ)])
    return pts


def clip_to_image(points_px: ArrayLike, width_px: int, height_px: int
                  ) -> NDArray[np.float64] | None:
    """The convex hull of image points clipped to the image rectangle (what a detector can
    see of a target at the border); None when nothing is left."""
    hull = cv2.convexHull(np.asarray(points_px, dtype=np.float32))
    area, poly = cv2.intersectConvexConvex(hull, _image_rect(width_px, height_px))
    if poly is None or area <= 1.0:
        return None
    seen: NDArray[np.float64] = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    return seen


def angle_costs(dims_a: NDArray[np.float64], long_a_deg: float, dims_b: NDArray[np.float64],
                long_b_deg: NDArray[np.float64], per_deg: float = 1.0 / 45.0
                ) -> NDArray[np.float64]:
    """:func:`angle_cost` of one rectangle against (n,) rectangles (``dims_b`` (n, 2))."""
    d = np.abs((long_a_deg - long_b_deg + 90.0) % 180.0 - 90.0)
    elong_b = dims_b[:, 1] / np.maximum(dims_b[:, 0], 1e-9)
    elong = np.minimum(dims_a[1] / max(dims_a[0], 1e-9), elong_b) - 1.0
    costs: NDArray[np.float64] = d * per_deg * np.clip(elong / 0.3, 0.0, 1.0)
    return costs


def plane_hits(cam_ned: Pose, model: CameraModel, pixels: ArrayLike, plane_down_m: float
               ) -> NDArray[np.float64]:
    """:func:`plane_hit` of (n, 2) pixels: (n, 3), NaN rows where the ray misses."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if len(px) == 0:
        return np.full((0, 3), np.nan)
    # R @ ray per row (a stacked matrix-vector product: the same rounding as plane_hit's)
    rays = (cam_ned.R[None] @ model.rays_optical(px)[:, :, None])[:, :, 0]
    return ray_plane_points(tuple(cam_ned.t), rays, plane_down_m, min_down=1e-3)


def seen_mbr(model: CameraModel, corners_px: ArrayLike
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], float] | None:
    """The :func:`mbr` of the part of a detection's MBR inside the image (it may reach past
    the border: compare what lies inside), None when nothing of it with an area is inside."""
    seen = clip_to_image(np.asarray(corners_px, dtype=np.float64), model.width_px,
                         model.height_px)
    if seen is None:
        return None
    centre, dims, long_deg = mbr(seen)
    return (centre, dims, long_deg) if (dims > 0).all() else None


def fit_on_top_plane(model: CameraModel, cam_ned: Pose, center_px: ArrayLike,
                     corners_px: ArrayLike, target: TargetConfig, *, ground_down_m: float = 0.0,
                     yaw_step_deg: float = 15.0, iterations: int = 3,
                     yaw_hint_deg: float | None = None,
                     region_hint: str | None = None,
                     occluder_px: ArrayLike | None = None) -> PlaneFit | None:
    """Top-face centre of the target whose top face or box silhouette best explains a
    detection (see the module docstring); None when the ray misses the plane or the model
    does not project in front of the camera.

    The projected model is clipped to the image like the detection, so a target cut by the
    image border (the final metres of the approach) still fits; ``yaw_hint_deg`` /
    ``region_hint`` (from earlier, complete views) restrict the headings to +-``yaw_step_deg``
    (7 headings) and the region model, since a cut view constrains them poorly.
    ``occluder_px`` (a convex polygon: the arm's tool, nearer than the target) is removed from
    each projected model as from the detection it hides (:func:`visible_mbr`).

    All (heading, region) hypotheses are iterated together: projections and ray-plane
    intersections are batched, only the clipping and the MBR (OpenCV) run per hypothesis.
    Same fits as :func:`fit_on_top_plane_reference` (tests/estimators/test_top_plane.py)."""
    plane = ground_down_m - float(target.height_m)
    to_cam = cam_ned.inverse()
    det = seen_mbr(model, corners_px)
    if det is None:
        return None
    c_det, dims_det, long_det = det
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
    occ = None if occluder_px is None else np.asarray(occluder_px, np.float32).reshape(-1, 2)
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
        fin = np.asarray(np.isfinite(px).all(axis=2))
        fin = fin[:, 8] & fin[:, :4].all(axis=1) & ((n_pts[idx] == 4) | fin[:, 4:8].all(axis=1))
        px32 = px.astype(np.float32)  # what OpenCV sees (clip_to_image, mbr)
        c_model = np.zeros((k, 2))
        for j, h in enumerate(idx):
            rect = _clipped_mbr(px32[j, :n_pts[h]], image_rect, occ) if fin[j] else None
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


def fit_on_top_plane_reference(model: CameraModel, cam_ned: Pose, center_px: ArrayLike,
                               corners_px: ArrayLike, target: TargetConfig, *,
                               ground_down_m: float = 0.0, yaw_step_deg: float = 15.0,
                               iterations: int = 3,
                               yaw_hint_deg: float | None = None,
                               region_hint: str | None = None,
                               occluder_px: ArrayLike | None = None) -> PlaneFit | None:
    """The straightforward implementation of :func:`fit_on_top_plane` (one hypothesis at a
    time), kept as the reference its tests compare the batched path against."""
    plane = ground_down_m - float(target.height_m)
    to_cam = cam_ned.inverse()
    det = seen_mbr(model, corners_px)
    if det is None:
        return None
    c_det, dims_det, long_det = det
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
                if occluder_px is None:
                    c_model, dims, long_model = mbr(seen)
                else:
                    rect = visible_mbr(seen.astype(np.float32),
                                       np.asarray(occluder_px, np.float32))
                    if rect is None:
                        dims = None
                        break
                    c_model, dims, long_model = rect_fields(rect)
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


def polygon_iou(a_px: NDArray[np.float32], b_px: NDArray[np.float32]) -> float:
    """Intersection over union of two convex polygons (float32 (N, 2) each)."""
    inter, _ = cv2.intersectConvexConvex(a_px, b_px)
    union = cv2.contourArea(a_px) + cv2.contourArea(b_px) - inter
    return float(inter / union) if union > 0 else 0.0


def polygon_centroid(poly_px: NDArray[np.float32]) -> NDArray[np.float64]:
    """Area centroid of a polygon (its vertices' mean when it has no area)."""
    m = cv2.moments(poly_px)
    if abs(m["m00"]) < 1e-9:
        centre: NDArray[np.float64] = poly_px.reshape(-1, 2).mean(axis=0).astype(np.float64)
        return centre
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def silhouette_iou(model: CameraModel, cam_ned: Pose, hull_px: ArrayLike, top_down_m: float,
                   target: TargetConfig, *, coarse_step_deg: float = 15.0,
                   fine_step_deg: float = 3.0, iterations: int = 3,
                   min_side_px: float = 30.0,
                   scales: Sequence[float] = (0.94, 0.97, 1.0, 1.03, 1.06)
                   ) -> tuple[float, float, str] | None:
    """How well the target's shape explains a detected region's outline (not in the paper).

    The target's top face (``"top"``) or whole box (``"box"``) is placed with its top on the
    plane ``down = top_down_m`` (NED) where its projected corners' mean meets the outline's
    centroid (``iterations`` ray-plane steps, as :func:`fit_on_top_plane` places MBR centres),
    moved in the image to remove the residual offset, scaled about its centroid by the best of ``scales`` (the camera's focal-length
    and range errors change the apparent size by a few %: without it the campaign's true
    targets, 3 % focal error, fit at IoU 0.82-0.9 in the wide camera), and the two outlines
    (convex hulls) are compared by intersection over union, over
    headings ``coarse_step_deg`` apart, then ``fine_step_deg`` apart around the best. Returns
    the best (IoU, heading deg in [0, 180), region), None when no model projects or the
    outline's minimum-area rectangle is narrower than ``min_side_px`` (a region a few pixels
    across has little shape: over ``benchmarks/fault_campaign.py --runs 200 --seed 3 --binning 2``
    true targets' IoUs have their 1st percentile at 0.89 for 20-30 px, 0.91 for 30-50 px and
    0.96 above 100 px; docs/mission.md, "Candidate rejection by shape").

    A region's minimum bounding rectangle has three numbers (two sides and a direction), which
    a box of another shape but the target's colour and top area can match at some heading
    (a 0.32 m square box for the 0.40 x 0.25 m target: tests/missions/test_candidate_rejection.py);
    its outline cannot:
    such a box's best IoU stays near 0.8 where the target's is near 1 (docs/mission.md).
    """
    det = np.asarray(hull_px, dtype=np.float32).reshape(-1, 2)
    if len(det) < 3 or not np.isfinite(det).all() or cv2.contourArea(det) <= 1.0:
        return None
    if min(cv2.minAreaRect(det)[1]) < min_side_px:
        return None
    c_det = polygon_centroid(det)
    p0 = plane_hit(cam_ned, model, c_det, top_down_m)
    if p0 is None:
        return None
    to_cam = cam_ned.inverse()

    hl, hw = target.length_m / 2, target.width_m / 2
    local = np.array([[hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw]])

    def best_of(hyps: list[tuple[float, str]]) -> tuple[float, float, str] | None:
        p = np.repeat(p0[None, :], len(hyps), axis=0)
        alive = np.ones(len(hyps), dtype=bool)
        ious = np.zeros(len(hyps))
        hulls: dict[int, NDArray[np.float64]] = {}
        yaw = np.radians([h[0] for h in hyps])
        rot = np.stack([np.stack([np.cos(yaw), -np.sin(yaw)], -1),
                        np.stack([np.sin(yaw), np.cos(yaw)], -1)], 1)  # (n, 2, 2)
        offsets = np.einsum("nij,kj->nki", rot, local)  # (n, 4, 2) as box_points_ned
        for it in range(iterations + 1):
            idx = np.flatnonzero(alive)
            if len(idx) == 0:
                return None
            pts = np.empty((len(idx), 9, 3))
            pts[:, :4, :2] = p[idx, None, :2] + offsets[idx]
            pts[:, :4, 2] = p[idx, None, 2]
            pts[:, 4:8, :2] = pts[:, :4, :2]
            pts[:, 4:8, 2] = pts[:, :4, 2] + target.height_m
            pts[:, 8] = p[idx]
            px = model.project(to_cam.apply(pts.reshape(-1, 3))).reshape(len(idx), 9, 2)
            box = np.array([hyps[h][1] == "box" for h in idx])
            fin = np.isfinite(px[:, 8]).all(axis=1) & np.isfinite(px[:, :4]).all(axis=(1, 2)) \
                & (~box | np.isfinite(px[:, 4:8]).all(axis=(1, 2)))
            alive[idx[~fin]] = False
            if it == iterations:  # placed: each outline against the detection's
                for j in np.flatnonzero(fin):
                    h = int(idx[j])
                    corners = px[j, :8] if box[j] else px[j, :4]
                    hull = np.asarray(cv2.convexHull(corners.astype(np.float32)),
                                      dtype=np.float32).reshape(-1, 2)
                    hulls[h] = hull - polygon_centroid(hull)  # the residual offset removed
                    ious[h] = polygon_iou(det, (hulls[h] + c_det).astype(np.float32))
                break
            # move each model so its projected corners' mean meets the outline's centroid
            # (the mean stands in for the outline's centroid while placing: vectorised)
            mean = np.where(box[:, None], px[:, :8].mean(axis=1), px[:, :4].mean(axis=1))
            hits = plane_hits(cam_ned, model, (px[:, 8] + c_det - mean)[fin], top_down_m)
            ok = np.isfinite(hits).all(axis=1)
            alive[idx[fin][~ok]] = False
            p[idx[fin][ok]] = hits[ok]
        if not alive.any():
            return None
        # the best few again at the scales the camera's focal and mount errors leave
        top = [int(h) for h in np.flatnonzero(alive)[np.argsort(-ious[alive])[:3]]]
        for h in top:
            ious[h] = max(polygon_iou(det, (hulls[h] * f + c_det).astype(np.float32))
                          for f in scales)
        k = max(top, key=lambda h: ious[h])
        return float(ious[k]), hyps[k][0] % 180.0, hyps[k][1]

    coarse = best_of([(float(y), r) for y in np.arange(0.0, 180.0, coarse_step_deg)
                      for r in REGIONS])
    if coarse is None:
        return None
    half = coarse_step_deg - fine_step_deg
    fine = best_of([(float(coarse[1] + d), coarse[2])
                    for d in np.arange(-half, half + 1e-9, fine_step_deg)])
    return coarse if fine is None or fine[0] < coarse[0] else fine


class TopPlaneFitter:
    """Plugin ``top_plane`` (role ``fitters``): :func:`fit_on_top_plane` behind the
    :class:`~eaglemission.interfaces.fitter.PlaneFitter` Protocol (not in the paper:
    docs/estimators.md, "top-plane fit")."""

    description: ClassVar[str] = ("top face or box silhouette of the target fitted on the plane of its top "
                   "(MBR centre, side lengths and direction over a grid of headings)")

    class Config(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        yaw_step_deg: float = Field(default=15.0, gt=0, le=90, description="heading grid step")

    def __init__(self, config: Config | None = None, *, target: TargetConfig,
                 **_context: object) -> None:
        self.config: TopPlaneFitter.Config = config or self.Config()
        self.target = target

    def fit(self, detection: Detection, view: CameraView, *, plane_down_m: float,
            yaw_hint_deg: float | None = None, region_hint: str | None = None,
            iterations: int = 4, silhouette: bool = False,
            yaw_hint_span_deg: float | None = None,
            occluder_px: ArrayLike | None = None) -> PlaneFit | None:
        if region_hint is not None and region_hint not in REGIONS:
            raise ValueError(f"region_hint: must be one of {REGIONS}, got {region_hint!r}")
        fit = fit_on_top_plane(view.model, view.camera_pose_ned, detection.center_px,
                               detection.corners_px, self.target, ground_down_m=plane_down_m,
                               yaw_step_deg=(self.config.yaw_step_deg
                                             if yaw_hint_deg is None or yaw_hint_span_deg is None
                                             else yaw_hint_span_deg),
                               iterations=iterations,
                               yaw_hint_deg=yaw_hint_deg, region_hint=region_hint,
                               occluder_px=occluder_px)
        if fit is None or not silhouette or detection.hull_px is None \
                or yaw_hint_deg is not None:
            return fit  # a cut view (hinted) shows only part of the outline
        sil = silhouette_iou(view.model, view.camera_pose_ned, detection.hull_px,
                             fit.position_ned_m[2], self.target)
        return fit if sil is None else replace(fit, silhouette_iou=sil[0],
                                               silhouette_yaw_deg=sil[1])
