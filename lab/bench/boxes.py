"""Box-annotated sequences: ``boxes.txt`` parsing and the per-frame box metrics of ``bench``.

A box sequence is ``<seq>/frames/*.jpg`` plus ``<seq>/boxes.txt``: one ``x,y,w,h`` line per frame
in frame order (commas, tabs or spaces), pixels, ``nan`` for a frame without the target (fully
occluded or out of view). The UAV tracking sets (UAV123, UAVDT, DTB70) come from MATLAB (OTB-style)
toolkits, so ``x, y`` are **1-based**: the box covers the pixel columns ``x .. x + w - 1`` counted
from 1. ``parse_boxes(text, origin=1)`` (the default) converts them to the conventions of
docs/conventions.md (``(u, v)``, origin at the centre of the top-left pixel): the box's edges are
``u_min = x - origin - 0.5``, ``u_max = u_min + w`` (and the same for v), so a 1-based box at
``x = 1, w = 10`` spans the pixel centres 0..9. ``origin=0`` reads 0-based files.

Metrics of one frame against its box (docs/detectors.md, "Box metrics"):

- **on target**: the best-ranked detection's centre inside the box grown by 25 % of its width
  (height) on each side (``grow_box``);
- **IoU**: intersection over union of the best detection's rotated MBR with the (ungrown) box;
- **saliency peak on target**: the map's maximum over the grown box equals its global maximum
  (a non-constant map; ties count as on target);
- **false detections**: detections whose centre lies outside the grown box (every detection of a
  frame without the target);
- **any**: the frame has at least one detection;
- **on the mask** (mask sequences only): the best-ranked detection's centre, rounded to the
  nearest pixel, lies on a ground-truth mask pixel: stricter than *on target*, whose grown
  bounding box also holds background (a detection on the top edge of a car's box is on target
  but not on the car).

References
----------
Y. Wu, J. Lim, M.-H. Yang, "Online Object Tracking: A Benchmark", CVPR 2013 (the OTB annotation
format), DOI 10.1109/CVPR.2013.312.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from eaglemission.types import Detection, DetectionResult

#: Box as (u_min, v_min, u_max, v_max): pixel *edges* in the conventions' (u, v) coordinates.
Box = NDArray[np.float64]

GROW_FRACTION = 0.25
_SPLIT = re.compile(r"[,\s;]+")


class BoxFormatError(ValueError):
    """A ``boxes.txt`` line is not ``x,y,w,h`` (four numbers or nan)."""


def parse_boxes(text: str, *, origin: int = 1, source: str = "boxes.txt") -> NDArray[np.float64]:
    """Boxes of a ``boxes.txt`` as an (N, 4) array of (u_min, v_min, u_max, v_max).

    Parameters
    ----------
    text : str
        One ``x,y,w,h`` line per frame (separators: comma, tab, space or semicolon). A line with
        any ``nan`` (any case) is a frame without the target and gives a row of NaN. Blank lines
        at the end are ignored; a blank line before the last box is an error (it would shift
        every later box by a frame).
    origin : {1, 0}
        Index of the first pixel in the file: 1 for MATLAB/OTB-style annotations (UAV123, UAVDT,
        DTB70), 0 for 0-based ones.
    source : str
        Name used in error messages.

    Returns
    -------
    ndarray of shape (N, 4), float64
        Pixel edges in docs/conventions.md coordinates (pixel centres at integers):
        ``u_min = x - origin - 0.5``, ``u_max = u_min + w``.

    Raises
    ------
    BoxFormatError
        A line without four numbers, a negative or zero size, or an inner blank line.
    """
    if origin not in (0, 1):
        raise ValueError(f"origin: must be 0 or 1, got {origin!r}")
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    out = np.full((len(lines), 4), np.nan)
    for i, line in enumerate(lines):
        fields = [f for f in _SPLIT.split(line.strip()) if f]
        if len(fields) != 4:
            raise BoxFormatError(f"{source}:{i + 1}: expected x,y,w,h (4 numbers or nan), got "
                                 f"{line.strip()!r}")
        try:
            x, y, w, h = (float(f) for f in fields)
        except ValueError:
            raise BoxFormatError(f"{source}:{i + 1}: not a number in {line.strip()!r}") from None
        if any(math.isnan(v) for v in (x, y, w, h)):
            continue
        if not all(math.isfinite(v) for v in (x, y, w, h)) or w <= 0 or h <= 0:
            raise BoxFormatError(f"{source}:{i + 1}: need finite x, y and w, h > 0, got "
                                 f"{line.strip()!r}")
        u0, v0 = x - origin - 0.5, y - origin - 0.5
        out[i] = (u0, v0, u0 + w, v0 + h)
    return out


def box_valid(box: Box) -> bool:
    """Whether the frame has a target box (no NaN)."""
    return bool(np.all(np.isfinite(box)))


def grow_box(box: Box, fraction: float = GROW_FRACTION) -> Box:
    """The box grown by ``fraction`` of its width (height) on each side."""
    u0, v0, u1, v1 = (float(c) for c in box)
    du, dv = fraction * (u1 - u0), fraction * (v1 - v0)
    return np.array([u0 - du, v0 - dv, u1 + du, v1 + dv])


def point_in_box(u: float, v: float, box: Box) -> bool:
    """``(u, v)`` inside the box (edges included)."""
    return bool(box[0] <= u <= box[2] and box[1] <= v <= box[3])


def box_from_mask(mask: NDArray[np.bool_]) -> Box:
    """Bounding box (pixel edges) of a binary mask; NaN when the mask is empty."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return np.full(4, np.nan)
    return np.array([cols[0] - 0.5, rows[0] - 0.5, cols[-1] + 0.5, rows[-1] + 0.5])


def box_corners(box: Box) -> NDArray[np.float64]:
    """The box's 4 corners, clockwise on screen from the top-left (docs/conventions.md)."""
    u0, v0, u1, v1 = (float(c) for c in box)
    return np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]])


def polygon_iou(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Intersection over union of two convex polygons, (N, 2) and (M, 2) vertices."""
    pa = np.asarray(a, np.float32).reshape(-1, 1, 2)
    pb = np.asarray(b, np.float32).reshape(-1, 1, 2)
    area_a, area_b = abs(cv2.contourArea(pa)), abs(cv2.contourArea(pb))
    if area_a <= 0 or area_b <= 0:
        return 0.0
    inter, _ = cv2.intersectConvexConvex(pa, pb)
    inter = max(0.0, float(inter))
    union = area_a + area_b - inter
    return inter / union if union > 0 else 0.0


def detection_iou(det: Detection, box: Box) -> float:
    """IoU of a detection's rotated MBR with an axis-aligned box."""
    return polygon_iou(det.corners_px, box_corners(box))


def point_on_mask(u: float, v: float, mask: NDArray[np.bool_]) -> bool:
    """Whether ``(u, v)``, rounded to the nearest pixel, is a mask pixel (False outside)."""
    c, r = int(round(u)), int(round(v))
    return bool(0 <= r < mask.shape[0] and 0 <= c < mask.shape[1] and mask[r, c])


def peak_on_target(saliency: NDArray[np.floating], grown: Box) -> bool:
    """Whether the map's global maximum is reached inside the grown box (pixel centres inside).

    A constant map (no peak) is never on target; ties count as on target.
    """
    s = np.asarray(saliency)
    h, w = s.shape
    c0, r0 = max(0, math.ceil(grown[0])), max(0, math.ceil(grown[1]))
    c1, r1 = min(w - 1, math.floor(grown[2])), min(h - 1, math.floor(grown[3]))
    if c1 < c0 or r1 < r0:
        return False
    lo, hi = cv2.minMaxLoc(np.ascontiguousarray(s, np.float32))[:2]
    if not hi > lo:
        return False
    return bool(float(s[r0:r1 + 1, c0:c1 + 1].max()) >= hi)


@dataclass(frozen=True)
class FrameBoxScore:
    """Box metrics of one frame (``has_target`` False: only ``n_false`` and ``n_detections``;
    ``best_on_mask`` None: the frame has no mask)."""

    has_target: bool
    peak_on_target: bool
    best_on_target: bool
    iou: float
    n_detections: int
    n_false: int
    best_on_mask: bool | None = None


def score_frame(result: DetectionResult, box: Box, grow_fraction: float = GROW_FRACTION, *,
                mask: NDArray[np.bool_] | None = None) -> FrameBoxScore:
    """Box metrics of one detector result against the frame's box (NaN: no target) and, when
    given, its ground-truth mask (``best_on_mask``)."""
    dets = result.detections
    best = dets[0] if dets else None
    on_mask = None if mask is None else (
        best is not None and point_on_mask(*best.center_px, mask))
    if not box_valid(box):
        return FrameBoxScore(False, False, False, 0.0, len(dets), len(dets), on_mask)
    grown = grow_box(box, grow_fraction)
    hits = [point_in_box(*d.center_px, grown) for d in dets]
    return FrameBoxScore(
        True, peak_on_target(result.saliency, grown), bool(hits and hits[0]),
        detection_iou(best, box) if best is not None else 0.0, len(dets),
        sum(not h for h in hits), on_mask)


@dataclass
class BoxScores:
    """Running box metrics over frames (one sequence, or pooled)."""

    frames: int = 0  # scored frames, with or without the target
    target_frames: int = 0
    peak_hits: int = 0
    best_hits: int = 0
    any_frames: int = 0  # target frames with >= 1 detection
    sum_iou: float = 0.0
    detections: int = 0
    false_detections: int = 0
    mask_frames: int = 0  # scored frames with a ground-truth mask
    mask_hits: int = 0
    per_frame: list[FrameBoxScore] = field(default_factory=list, repr=False)

    def add(self, s: FrameBoxScore) -> None:
        self.frames += 1
        if s.best_on_mask is not None:
            self.mask_frames += 1
            self.mask_hits += s.best_on_mask
        self.detections += s.n_detections
        self.false_detections += s.n_false
        if s.has_target:
            self.target_frames += 1
            self.peak_hits += s.peak_on_target
            self.best_hits += s.best_on_target
            self.any_frames += s.n_detections > 0
            self.sum_iou += s.iou

    def merge(self, other: BoxScores) -> None:
        for k in ("frames", "target_frames", "peak_hits", "best_hits", "any_frames", "sum_iou",
                  "detections", "false_detections", "mask_frames", "mask_hits"):
            setattr(self, k, getattr(self, k) + getattr(other, k))

    @property
    def peak_rate(self) -> float:
        return self.peak_hits / self.target_frames if self.target_frames else math.nan

    @property
    def on_target_rate(self) -> float:
        return self.best_hits / self.target_frames if self.target_frames else math.nan

    @property
    def on_mask_rate(self) -> float:
        """Frames whose best detection's centre is on the mask, over the frames with a mask
        (NaN: none)."""
        return self.mask_hits / self.mask_frames if self.mask_frames else math.nan

    @property
    def any_rate(self) -> float:
        return self.any_frames / self.target_frames if self.target_frames else math.nan

    @property
    def mean_iou(self) -> float:
        """Mean IoU of the best detection over target frames (0 for a frame without one)."""
        return self.sum_iou / self.target_frames if self.target_frames else math.nan

    @property
    def false_per_frame(self) -> float:
        return self.false_detections / self.frames if self.frames else math.nan

    def as_dict(self) -> dict[str, float | int]:
        return {"frames": self.frames, "target_frames": self.target_frames,
                "peak_on_target": self.peak_rate, "best_on_target": self.on_target_rate,
                "best_on_mask": self.on_mask_rate, "mask_frames": self.mask_frames,
                "mean_iou": self.mean_iou, "frames_with_detection": self.any_rate,
                "detections_per_frame": self.detections / self.frames if self.frames else math.nan,
                "false_per_frame": self.false_per_frame}


def spread(values: Sequence[float]) -> dict[str, float]:
    """Mean, standard deviation, min and max of per-sequence figures (NaN ignored)."""
    v = np.asarray([x for x in values if not math.isnan(x)], np.float64)
    if v.size == 0:
        return {"mean": math.nan, "std": math.nan, "min": math.nan, "max": math.nan}
    return {"mean": float(v.mean()), "std": float(v.std()), "min": float(v.min()),
            "max": float(v.max())}


def crop_box(image: NDArray[np.uint8], box: Box) -> NDArray[np.uint8]:
    """The pixels whose centres lie inside ``box`` (clipped to the image), as a copy."""
    h, w = image.shape[:2]
    c0, r0 = max(0, math.ceil(box[0])), max(0, math.ceil(box[1]))
    c1, r1 = min(w, math.floor(box[2]) + 1), min(h, math.floor(box[3]) + 1)
    if c1 <= c0 or r1 <= r0:
        raise ValueError(f"box {tuple(np.round(box, 1))} lies outside the {w}x{h} image")
    return image[r0:r1, c0:c1].copy()
