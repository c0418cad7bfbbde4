"""The ``faulty`` camera: wraps a real camera plugin and injects the ``faults:`` section's camera
faults where they happen in life, in the camera driver.

* ``camera_drop``: no frame (:class:`~eaglemission.errors.GrabTimeout`);
* ``camera_freeze``: the last frame again, same image, stamp and sequence number (a driver
  re-delivering a stale buffer);
* ``corrupted_frame``: a frame of the right size full of noise;
* ``truncated_frame``: a frame cut short (only the top rows arrived);
  (these two spoil every frame grabbed in their window, and at least the first one grabbed
  after they start, however short the window);
* ``exposure_jump``: the image scaled by a gain (``size``) and clipped;
* ``camera_device_loss``: :class:`~eaglemission.errors.CameraLost` from then on;
* ``camera_clock_jump``: frame stamps shifted by ``size`` seconds from then on;
* ``occlusion``: the target painted over with the ground around it (from the world's truth).

The assembly inserts it (:mod:`eaglemission.lab.faults.injection`); it is not configured directly.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from eaglemission.lab.faults.schedule import ActiveFaults
from pydantic import BaseModel, ConfigDict

from eaglemission import errors
from eaglemission.types import Frame


class FaultyCameraConfig(BaseModel):
    """No params: the faults come from the mission file's ``faults:`` section."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class FaultyCamera:
    """Plugin ``faulty``: a camera with injected faults around ``inner``."""

    Config = FaultyCameraConfig
    description = ("wraps another camera and injects the `faults:` section's camera faults "
                   "(inserted by the assembly, not configured directly)")

    def __init__(self, config: FaultyCameraConfig | None = None, *, inner: Any = None,
                 faults: ActiveFaults | None = None, clock: Any = None, world: Any = None,
                 **_context: Any) -> None:
        if inner is None or faults is None or clock is None:
            raise errors.ConfigError("cameras: the `faulty` camera wraps another camera and is "
                                     "inserted by the assembly for a `faults:` section; "
                                     "configure a real camera type")
        self.inner, self.faults, self.clock, self.world = inner, faults, clock, world
        self.camera_id: str = inner.camera_id
        self.model = inner.model
        self._last: Frame | None = None

    @property
    def frame_rate_hz(self) -> float:
        return float(getattr(self.inner, "frame_rate_hz", float("inf")))

    def summary(self) -> str:
        fn = getattr(self.inner, "summary", None)
        return ("faults injected" + (f" around {fn()}" if callable(fn) else ""))

    def open(self) -> None:
        self.inner.open()

    def close(self) -> None:
        self.inner.close()

    def __enter__(self) -> FaultyCamera:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _on(self, kind: str, now_ns: int) -> Any:
        return self.faults.active(kind, now_ns, self.camera_id)

    def grab(self, *, timeout_s: float) -> Frame:
        now = self.clock.now_ns()
        if self._on("camera_device_loss", now):
            raise errors.CameraLost("DEVICE_LOST", f"camera {self.camera_id!r}.grab()", None,
                                    "the device stopped answering (injected fault)")
        if self._on("camera_drop", now):
            raise errors.GrabTimeout(self.camera_id, timeout_s)
        if self._on("camera_freeze", now) and self._last is not None:
            return self._last
        frame: Frame = self.inner.grab(timeout_s=timeout_s)
        self._last = frame
        img = frame.image
        stamp = frame.timestamp_ns
        if self._on("occlusion", now):
            img = self._occlude(frame)
        gain = self._on("exposure_jump", now)
        if gain is not None:
            img = np.clip(img.astype(np.float32) * gain.value, 0, 255).astype(np.uint8)
        if self.faults.frame_fault("corrupted_frame", now, self.camera_id):
            rng = np.random.default_rng(frame.seq)
            img = rng.integers(0, 256, size=img.shape, dtype=np.uint8)
        if self.faults.frame_fault("truncated_frame", now, self.camera_id):
            img = img[: max(1, int(img.shape[0] * 0.6))].copy()
        device_ns = frame.device_timestamp_ns
        jump = self._on("camera_clock_jump", now)
        if jump is not None:  # the device's clock jumps: its stamps and the mapped ones
            stamp += int(round(jump.value * 1e9))
            if device_ns is not None:
                device_ns += int(round(jump.value * 1e9))
        if img is frame.image and stamp == frame.timestamp_ns:
            return frame
        return Frame(img, stamp, frame.camera_id, frame.seq, frame.exposure_s, device_ns)

    def _occlude(self, frame: Frame) -> Any:
        """The target covered with the ground colour around it (a cover larger than it)."""
        if self.world is None:
            return frame.image
        truth = self.world.truth(self.camera_id, frame.seq)
        if not truth.target_visible or len(truth.target_polygon_px) < 3:
            return frame.image
        img = frame.image.copy()
        poly = np.asarray(truth.target_polygon_px, dtype=np.float64)
        c = poly.mean(axis=0)
        big = c + (poly - c) * 1.6
        mask = np.zeros(img.shape[:2], np.uint8)
        cv2.fillPoly(mask, [np.round(big).astype(np.int32)], 255)
        ring = cv2.bitwise_and(cv2.dilate(mask, np.ones((15, 15), np.uint8)),
                               cv2.bitwise_not(mask))
        colour = np.median(img[ring > 0], axis=0) if (ring > 0).any() else img.mean((0, 1))
        img[mask > 0] = colour.astype(np.uint8)
        return img
