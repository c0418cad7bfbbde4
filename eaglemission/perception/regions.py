"""Saliency map -> detections, shared by every detector (paper Sec. 4.2).

Normalise to 0..255, threshold (the paper's fixed T = 120; adaptive: a fraction of the
frame's peak above an absolute floor, Otsu or k x mean),
connected regions, minimum bounding rectangle (rotated, ``cv2.minAreaRect``) with its 4 corners
ordered as docs/conventions.md fixes (clockwise on screen from the top-left), filtered by the
target prior (projected area range, aspect ratio), ranked by score.

Conventions (docs/detectors.md, "Regions"):

- a pixel belongs to a region when its 8-bit value is strictly above the threshold
  (``sal8 > T``, OpenCV's ``THRESH_BINARY``); regions are 8-connected outer contours (holes
  are part of the region);
- the MBR is fitted to the pixel centres of the region's outline and, by default
  (``mbr_pixel_edges``), grown by half a pixel on every side so that its corners lie on the
  pixel *edges*: a 10 x 6 pixel block gives a 10 x 6 rectangle, not 9 x 5, which matters to the
  PnP of a target a few tens of pixels wide;
- ``Detection.angle_deg`` is the direction of the rectangle's long side, from +u towards +v
  (clockwise on screen), in [-90, 90);
- the score is the region's mean saliency times the square root of its pixel area.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.geometry import order_corners
from eaglemission.types import Detection, Saliency, TargetPrior


class RegionsConfig(BaseModel):
    """Threshold and region filter settings (every detector's ``regions`` section).

    ``normalize: none`` takes the map as the detector gives it in [0, 1] (each detector keeps an
    absolute scale, so an empty scene can stay below the threshold); ``minmax`` stretches every
    map to 0..255 first, as the paper does, which always makes the brightest spot reach 255 and
    therefore always fires on a fixed threshold (docs/paper_choices.md, "Regions").
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    threshold: Literal["fixed", "otsu", "mean", "adaptive"] = "fixed"
    fixed_threshold: int = Field(120, ge=1, le=254, description="T of the paper, on 0..255")
    mean_factor: float = Field(3.0, gt=0, description="k of the k x mean adaptive threshold")
    adaptive_floor: int = Field(40, ge=1, le=254, description=(
        "adaptive: the lowest T, on 0..255 (a map below it everywhere has no region)"))
    peak_fraction: float = Field(0.8, gt=0, lt=1, description=(
        "adaptive: T = max(adaptive_floor, peak_fraction x the map's maximum)"))
    normalize: Literal["minmax", "none"] = "none"
    min_area_px: float = Field(16.0, ge=1)
    max_area_frac: float | None = Field(None, gt=0, le=1, description=(
        "drop regions whose MBR covers more than this fraction of the image"))
    max_aspect: float | None = Field(None, ge=1, description=(
        "drop regions whose MBR is more elongated than this (long / short side)"))
    max_detections: int = Field(5, ge=1, le=100)
    mbr_pixel_edges: bool = True


def to_uint8(saliency: Saliency, normalize: str = "none") -> NDArray[np.uint8]:
    """Map a [0, 1] saliency map to 0..255 (optionally min-max stretched first).

    Values are rounded to nearest and saturated; NaN and negative values give 0. With
    ``normalize="minmax"`` a constant map gives all zeros.
    """
    s = np.asarray(saliency, dtype=np.float32)
    if normalize == "minmax":
        lo, hi = cv2.minMaxLoc(np.nan_to_num(s, nan=0.0, posinf=0.0, neginf=0.0))[:2]
        if not hi > lo:
            return np.zeros(s.shape, np.uint8)
        return np.asarray(cv2.convertScaleAbs(
            cv2.max(s - np.float32(lo), 0.0),  # type: ignore[call-overload]  # stubs lack max(Mat, scalar)
            alpha=255.0 / (hi - lo)), dtype=np.uint8)
    elif normalize != "none":
        raise ValueError(f"normalize: must be 'none' or 'minmax', got {normalize!r}")
    if not float(s.min()) >= 0.0:  # negative or NaN somewhere (a map in [0, 1]: one read)
        s = cv2.max(s, 0.0)  # type: ignore[call-overload]  # stubs lack max(Mat, scalar)
    return np.asarray(cv2.convertScaleAbs(s, alpha=255.0), dtype=np.uint8)


def adaptive_threshold(peak8: float, floor: float, fraction: float) -> float:
    """The adaptive threshold on 0..255: ``max(floor, fraction x peak)`` (docs/paper_choices.md,
    "Regions and evaluation").

    Sec. 3.2's "adaptive threshold segmentation" read as a segmentation relative to the frame's
    own peak (the region around the most salient spot, whatever the map's overall strength),
    above an absolute floor so that a map that stays low everywhere -- no target -- has no region.
    """
    return float(max(floor, fraction * peak8))


def binarize(sal8: NDArray[np.uint8], cfg: RegionsConfig) -> tuple[NDArray[np.uint8], float]:
    """Binary mask (0/255, ``sal8 > T``) and the threshold ``T`` used, on 0..255."""
    if cfg.threshold == "otsu":
        t, mask = cv2.threshold(sal8, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        return np.asarray(mask, dtype=np.uint8), float(t)
    if cfg.threshold == "mean":
        t = min(254.0, max(1.0, cfg.mean_factor * float(cv2.mean(sal8)[0])))
    elif cfg.threshold == "adaptive":
        peak = float(cv2.minMaxLoc(sal8)[1])
        t = min(254.0, adaptive_threshold(peak, cfg.adaptive_floor, cfg.peak_fraction))
    else:
        t = float(cfg.fixed_threshold)
    _, mask = cv2.threshold(sal8, t, 255, cv2.THRESH_BINARY)
    return np.asarray(mask, dtype=np.uint8), t


def prior_accepts(area_px: float, long_px: float, short_px: float,
                  prior: TargetPrior | None) -> bool:
    """Whether a rectangle fits the target prior (area range; aspect ratio within tolerance).

    The aspect test is relative: ``|long/short - ratio| <= tolerance * ratio``; a degenerate
    rectangle (``short == 0``) fails any aspect prior.
    """
    if prior is None:
        return True
    if not (prior.min_area_px <= area_px <= prior.max_area_px):
        return False
    if prior.aspect_ratio is not None:
        if short_px <= 0:
            return False
        ratio = long_px / short_px
        if abs(ratio - prior.aspect_ratio) > prior.aspect_tolerance * prior.aspect_ratio:
            return False
    return True


# another name for prior_accepts
_prior_ok = prior_accepts


def long_side_angle_deg(corners: NDArray[np.float64]) -> float:
    """Direction of the long side of an ordered rectangle, from +u towards +v, in [-90, 90)."""
    e1 = corners[1] - corners[0]
    e2 = corners[2] - corners[1]
    e = e1 if float(e1 @ e1) >= float(e2 @ e2) else e2
    a = math.degrees(math.atan2(float(e[1]), float(e[0])))
    return (a + 90.0) % 180.0 - 90.0


def outline_hull(points_px: ArrayLike, half_px: float = 0.5) -> NDArray[np.float64] | None:
    """Convex hull of a region's outline pixels taken as squares: each point (a pixel or block
    centre) stands for the square ``half_px`` around it, so the hull covers the region's pixels
    rather than passing through their centres (a 10 x 6 px block gives a 10 x 6 px hull, as the
    MBR does). (N, 2) float64; None when empty."""
    pts = np.asarray(points_px, dtype=np.float32).reshape(-1, 2)
    if len(pts) == 0:
        return None
    h = np.float32(half_px)
    squares = (pts[:, None, :] + np.array([[-h, -h], [h, -h], [h, h], [-h, h]],
                                          dtype=np.float32)[None]).reshape(-1, 2)
    hull: NDArray[np.float64] = cv2.convexHull(squares).reshape(-1, 2).astype(np.float64)
    return hull if len(hull) >= 3 else None


def find_regions(
    saliency: Saliency,
    cfg: RegionsConfig,
    prior: TargetPrior | None = None,
    *,
    camera_id: str = "",
) -> tuple[tuple[Detection, ...], float]:
    """Detections ranked by score and the threshold used, in [0, 1].

    Parameters
    ----------
    saliency : ndarray of shape (H, W), float32 in [0, 1]
    cfg : RegionsConfig
    prior : TargetPrior, optional
        Keeps only rectangles whose area (px^2) and aspect ratio fit the target.
    camera_id : str

    Returns
    -------
    detections : tuple of Detection
        At most ``cfg.max_detections``, best first (score = mean saliency x sqrt(pixel area)).
    threshold : float
        The threshold used, divided by 255.
    """
    sal8 = to_uint8(saliency, cfg.normalize)
    mask, t = binarize(sal8, cfg)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    grow = 1.0 if cfg.mbr_pixel_edges else 0.0
    sal = np.asarray(saliency, dtype=np.float32)
    image_area = float(sal.shape[0] * sal.shape[1])
    candidates: list[tuple[float, tuple[Sequence[float], tuple[float, float], float],
                           NDArray[Any]]] = []
    for cnt in contours:
        x, y, bw, bh = cv2.boundingRect(cnt)
        # boundingRect counts pixels, so bw * bh bounds every area below from above.
        if bw * bh < cfg.min_area_px:
            continue
        centre, (w, h), angle = cv2.minAreaRect(cnt)
        w, h = float(w) + grow, float(h) + grow
        rect_area = w * h
        if rect_area < cfg.min_area_px:
            continue
        if not prior_accepts(rect_area, max(w, h), min(w, h), prior):
            continue
        if cfg.max_area_frac is not None and rect_area > cfg.max_area_frac * image_area:
            continue
        if cfg.max_aspect is not None and max(w, h) > cfg.max_aspect * min(w, h):
            continue
        region = np.zeros((bh, bw), np.uint8)
        cv2.drawContours(region, [cnt], 0, 255, thickness=cv2.FILLED, offset=(-x, -y))
        region &= mask[y : y + bh, x : x + bw]
        n_px = cv2.countNonZero(region)
        mean_sal = cv2.mean(sal[y : y + bh, x : x + bw], mask=region)[0] if n_px else 0.0
        candidates.append((float(mean_sal) * math.sqrt(max(n_px, 1)), (centre, (w, h), angle),
                           cnt))
    candidates.sort(key=lambda c: c[0], reverse=True)
    found = []
    for score, rect, cnt in candidates[: cfg.max_detections]:
        (cu, cv), (w, h), _ = rect
        corners = order_corners(cv2.boxPoints(rect))
        found.append(Detection(
            score=score, center_px=(float(cu), float(cv)), corners_px=corners,
            size_px=(max(w, h), min(w, h)), angle_deg=long_side_angle_deg(corners),
            area_px=w * h, camera_id=camera_id,
            hull_px=outline_hull(cnt) if cfg.mbr_pixel_edges else outline_hull(cnt, 0.0),
        ))
    return tuple(found), t / 255.0


def reduced_prior(prior: TargetPrior | None, sx: float, sy: float) -> TargetPrior | None:
    """``prior`` for a map reduced by ``sx`` x ``sy`` (areas divided by ``sx sy``)."""
    if prior is None:
        return None
    return dataclasses.replace(prior, min_area_px=prior.min_area_px / (sx * sy),
                               max_area_px=prior.max_area_px / (sx * sy))


def to_frame_pixels(det: Detection, sx: float, sy: float) -> Detection:
    """A detection found on a map reduced by ``sx`` x ``sy`` (area average: map pixel ``k``
    covers frame pixels ``sx k`` to ``sx k + sx - 1``) in the frame's pixels: a point ``u``
    goes to ``sx u + (sx - 1) / 2`` (pixel centres and edges alike), sizes scale by ``sx``
    (``sy``), the area by ``sx sy`` and the score (mean x sqrt(pixel count)) by
    ``sqrt(sx sy)``."""
    off = np.array([(sx - 1.0) / 2.0, (sy - 1.0) / 2.0])
    k = np.array([sx, sy])
    corners = order_corners(np.asarray(det.corners_px) * k + off)
    hull = None if det.hull_px is None else np.asarray(det.hull_px) * k + off
    long_px, short_px = det.size_px
    if sx != sy:  # an anisotropic reduction: measure the scaled rectangle's sides
        sides = np.linalg.norm(np.diff(np.vstack([corners, corners[:1]]), axis=0), axis=1)
        long_px, short_px = float(max(sides[0], sides[1])), float(min(sides[0], sides[1]))
    else:
        long_px, short_px = long_px * sx, short_px * sx
    cu, cv = det.center_px
    return dataclasses.replace(
        det, score=det.score * math.sqrt(sx * sy),
        center_px=(float(sx * cu + off[0]), float(sy * cv + off[1])), corners_px=corners,
        size_px=(long_px, short_px), angle_deg=long_side_angle_deg(corners),
        area_px=det.area_px * sx * sy, hull_px=hull)
