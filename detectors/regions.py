"""Saliency map -> detections, shared by every detector (paper Sec. 4.2).

Normalise to 0..255, threshold (the paper's fixed T = 120, or adaptive: Otsu / k x mean),
connected regions, minimum bounding rectangle (rotated, ``cv2.minAreaRect``) with its 4 corners
ordered as docs/conventions.md fixes (clockwise on screen from the top-left), filtered by the
target prior (projected area range, aspect ratio), ranked by score.
"""

from __future__ import annotations

import math
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.types import Detection, Saliency, TargetPrior


class RegionsConfig(BaseModel):
    """Threshold and region filter settings (every detector's ``regions`` section)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    threshold: Literal["fixed", "otsu", "mean"] = "fixed"
    fixed_threshold: int = Field(120, ge=1, le=254, description="T of the paper, on 0..255")
    mean_factor: float = Field(3.0, gt=0, description="k of the k x mean adaptive threshold")
    normalize: Literal["minmax", "none"] = "none"
    min_area_px: float = Field(16.0, ge=1)
    max_detections: int = Field(5, ge=1, le=100)


def order_corners(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """Order 4 corners clockwise on screen (u right, v down) starting from the top-left one
    (smallest ``u + v``; ties broken by smaller ``v``)."""
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    centre = c.mean(axis=0)
    # On screen with v down, increasing atan2(v, u) turns clockwise.
    ang = np.arctan2(c[:, 1] - centre[1], c[:, 0] - centre[0])
    c = c[np.argsort(ang)]
    s = c[:, 0] + c[:, 1]
    start = int(np.lexsort((c[:, 1], s))[0])
    return np.roll(c, -start, axis=0)


def to_uint8(saliency: Saliency, normalize: str = "none") -> NDArray[np.uint8]:
    """Map a [0, 1] saliency map to 0..255 (optionally min-max stretched first)."""
    s = np.asarray(saliency, dtype=np.float32)
    if normalize == "minmax":
        lo, hi = float(s.min()), float(s.max())
        s = (s - lo) / (hi - lo) if hi > lo else np.zeros_like(s)
    return np.clip(s * 255.0 + 0.5, 0, 255).astype(np.uint8)


def binarize(sal8: NDArray[np.uint8], cfg: RegionsConfig) -> tuple[NDArray[np.uint8], float]:
    """Binary mask and the threshold used (0..255)."""
    if cfg.threshold == "otsu":
        t, mask = cv2.threshold(sal8, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        return mask, float(t)
    if cfg.threshold == "mean":
        t = min(254.0, max(1.0, cfg.mean_factor * float(sal8.mean())))
    else:
        t = float(cfg.fixed_threshold)
    _, mask = cv2.threshold(sal8, t, 255, cv2.THRESH_BINARY)
    return mask, t


def _prior_ok(area: float, long_: float, short: float, prior: TargetPrior | None) -> bool:
    if prior is None:
        return True
    if not (prior.min_area_px <= area <= prior.max_area_px):
        return False
    if prior.aspect_ratio is not None and short > 0:
        ratio = long_ / short
        if abs(ratio - prior.aspect_ratio) > prior.aspect_tolerance * prior.aspect_ratio:
            return False
    return True


def find_regions(
    saliency: Saliency,
    cfg: RegionsConfig,
    prior: TargetPrior | None = None,
    *,
    camera_id: str = "",
) -> tuple[tuple[Detection, ...], float]:
    """Detections ranked by score (mean saliency x sqrt(area)) and the threshold used, in [0, 1]."""
    sal8 = to_uint8(saliency, cfg.normalize)
    mask, t = binarize(sal8, cfg)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    found: list[Detection] = []
    for cnt in contours:
        area = float(cv2.contourArea(cnt))
        if area < cfg.min_area_px and len(cnt) < 3:
            continue
        (cu, cv), (w, h), angle = cv2.minAreaRect(cnt)
        rect_area = float(w * h)
        if max(area, rect_area) < cfg.min_area_px:
            continue
        long_, short = (w, h) if w >= h else (h, w)
        if not _prior_ok(rect_area, long_, short, prior):
            continue
        x, y, bw, bh = cv2.boundingRect(cnt)
        roi = saliency[y : y + bh, x : x + bw]
        roi_mask = mask[y : y + bh, x : x + bw] > 0
        mean_sal = float(roi[roi_mask].mean()) if roi_mask.any() else 0.0
        score = mean_sal * math.sqrt(max(area, 1.0))
        corners = order_corners(cv2.boxPoints(((cu, cv), (w, h), angle)))
        found.append(Detection(
            score=score, center_px=(float(cu), float(cv)), corners_px=corners,
            size_px=(float(long_), float(short)), angle_deg=float(angle), area_px=rect_area,
            camera_id=camera_id,
        ))
    found.sort(key=lambda d: d.score, reverse=True)
    return tuple(found[: cfg.max_detections]), t / 255.0
