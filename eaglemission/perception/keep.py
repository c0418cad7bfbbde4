"""Acquire, then keep (not in the paper): the detector finds and confirms the target, a tracker
keeps it between the detector's frames (docs/architecture.md, "Perception").

One :class:`TargetKeeper` per camera, a small state machine:

- **searching**: the detector runs on every frame; its chosen detection (stage 2 of the
  perception pipeline) on the same object in ``confirm_frames`` consecutive detector frames
  confirms the target, and the tracker starts on its box; the next frame follows the
  candidate first (:attr:`TargetKeeper.candidate`, the perception's stage 2);
- **keeping**: the tracker follows the box; every ``detect_every_frames``-th frame (every frame
  at close range, where the pose wants the detector's region) the detector re-checks. A chosen
  detection on the kept box is the target (the tracker restarts on it when their boxes overlap
  less than ``restart_iou``: drift, a change of size); one elsewhere in ``switch_after``
  re-checks in a row moves the keeper to it (with an example image of the target, only when it
  looks more like the example than the tracker's box: the detector may prefer another object);
  a tracker that loses the target hands the frame to the detector, and without a detection on
  it the keeper searches again.

Before the target is confirmed the keeper keeps nothing (:meth:`TargetKeeper.step` returns
None): what a frame shows before that is a candidate, not the target.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.geometry import order_corners
from eaglemission.interfaces.tracker import Box, Tracker
from eaglemission.types import Detection, Frame

AGREE_GROW = 0.25
"""A detection is on the kept box when its centre lies in the box grown by this fraction of its
width (height) on each side."""


class KeepConfig(BaseModel):
    """``tracker``: how the target is kept once the detector has confirmed it."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    confirm_frames: int = Field(2, ge=1, le=100, description=(
        "detector frames in a row whose chosen detection is on the same object before it is "
        "the target and the tracker starts"))
    detect_every_frames: int = Field(4, ge=1, le=100, description=(
        "while keeping, the detector re-checks every this many frames (every frame at close "
        "range)"))
    switch_after: int = Field(2, ge=1, le=100, description=(
        "re-checks in a row whose chosen detection lies off the kept box before the keeper "
        "moves to it"))
    restart_iou: float = Field(0.3, ge=0, le=1, description=(
        "a re-check's detection on the kept box restarts the tracker on its own box when the "
        "two overlap less than this (intersection over union)"))


@dataclass(frozen=True, slots=True)
class Kept:
    """The kept target in one frame: the detector's region on it, or the tracker's box."""

    detection: Detection
    from_tracker: bool


def _centre(box: Box) -> tuple[float, float]:
    return ((box[0] + box[2]) / 2, (box[1] + box[3]) / 2)


def box_of(det: Detection) -> Box:
    """The axis-aligned box around a detection's corners."""
    c = np.asarray(det.corners_px, np.float64)
    lo, hi = c.min(axis=0), c.max(axis=0)
    return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def on_box(point_px: tuple[float, float], box: Box, grow: float = AGREE_GROW) -> bool:
    u0, v0, u1, v1 = box
    gu, gv = grow * (u1 - u0), grow * (v1 - v0)
    return u0 - gu <= point_px[0] <= u1 + gu and v0 - gv <= point_px[1] <= v1 + gv


def box_iou(a: Box, b: Box) -> float:
    iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = iw * ih
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def box_detection(box: Box, camera_id: str, score: float = 0.0) -> Detection:
    """A tracker's box as a :class:`Detection`: its four corners, no outline."""
    u0, v0, u1, v1 = box
    corners = order_corners(np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], np.float64))
    w, h = u1 - u0, v1 - v0
    return Detection(score=score, center_px=((u0 + u1) / 2, (v0 + v1) / 2), corners_px=corners,
                     size_px=(max(w, h), min(w, h)), angle_deg=0.0 if w >= h else 90.0,
                     area_px=w * h, camera_id=camera_id)


class TargetKeeper:
    """The acquire-then-keep state of one camera (see the module docstring)."""

    def __init__(self, tracker: Tracker, config: KeepConfig | None = None) -> None:
        self.tracker = tracker
        self.config = config or KeepConfig()
        self.box: Box | None = None
        """The kept box (None: searching)."""
        self._candidate: Box | None = None
        self._seen = 0
        self._since_check = 0
        self._off = 0

    @property
    def keeping(self) -> bool:
        return self.box is not None

    @property
    def candidate(self) -> Box | None:
        """While searching, the candidate awaiting confirmation (None: none, or keeping): the
        next frame follows it first, where it was, so that it is not confirmed only when
        nothing else in view looks more like the target."""
        return None if self.box is not None else self._candidate

    def reset(self) -> None:
        self.box, self._candidate, self._seen, self._since_check, self._off = None, None, 0, 0, 0

    def detector_due(self, close_range: bool = False) -> bool:
        """Whether this frame needs the detector (the caller runs it, then calls :meth:`step`)."""
        return (not self.keeping or close_range
                or self._since_check + 1 >= self.config.detect_every_frames)

    def step(self, frame: Frame, chosen: Detection | None, detected: bool,
             likeness: Callable[[tuple[float, float]], float] | None = None) -> Kept | None:
        """The kept target in ``frame`` (None while searching). ``detected``: the detector ran
        on this frame; ``chosen``: its chosen detection (None: none); ``likeness``: how much
        the frame at a pixel looks like the target's example image (None: no example): a
        detection elsewhere moves the keeper only if it looks more like the example than the
        tracker's box does."""
        if not self.keeping:
            return self._search(frame, chosen) if detected else None
        tracked = self.tracker.update(frame)
        self._since_check += 1
        if not detected:
            if tracked is None:  # lost between re-checks: the next frame asks the detector
                self._since_check = self.config.detect_every_frames
                return None
            self.box = tracked
            return Kept(box_detection(tracked, frame.camera_id), True)
        self._since_check = 0
        if chosen is not None and (tracked is None or on_box(chosen.center_px, tracked)):
            self._off = 0
            box = box_of(chosen)
            if tracked is None or box_iou(box, tracked) < self.config.restart_iou:
                self.tracker.start(frame, box)
            self.box = box
            return Kept(chosen, False)
        if chosen is not None and (tracked is None or likeness is None or likeness(
                chosen.center_px) > likeness(_centre(tracked))):
            self._off += 1
            if self._off >= self.config.switch_after:  # the detector insists: move to it
                self._off = 0
                self.box = box_of(chosen)
                self.tracker.start(frame, self.box)
                return Kept(chosen, False)
        if tracked is None:  # neither the tracker nor the detector has it
            self.reset()
            return None
        self.box = tracked
        return Kept(box_detection(tracked, frame.camera_id), True)

    def correct(self, frame: Frame, box: Box) -> None:
        """Another measurement of the kept target in ``frame`` (at close range, the region of
        the target's colour measured where the tracker's box was): it becomes the kept box, and
        the tracker restarts on it when the two overlap less than ``restart_iou``."""
        if self.box is None:
            return
        if box_iou(box, self.box) < self.config.restart_iou:
            self.tracker.start(frame, box)
        self.box = box

    def _search(self, frame: Frame, chosen: Detection | None) -> Kept | None:
        if chosen is None:
            self._candidate, self._seen = None, 0
            return None
        box = box_of(chosen)
        same = self._candidate is not None and on_box(chosen.center_px, self._candidate)
        self._seen = self._seen + 1 if same else 1
        self._candidate = box
        if self._seen < self.config.confirm_frames:
            return None
        self.box = box
        self._since_check = self._off = 0
        self.tracker.start(frame, box)
        return Kept(chosen, False)
