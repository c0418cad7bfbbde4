"""Detector and estimator faults, injected around the plugins the assembly built (they happen
inside the perception software in life, so they wrap the role, not the mission).

* ``detector_exception``: ``detect`` raises;
* ``nan_map``: the saliency map is NaN, and so is every detection derived from it;
* ``slow_frame``: ``detect`` takes ``size`` seconds longer (wall time: virtual time stands
  still while perception works, so in simulation this costs wall time only);
* ``degenerate_corners``: the estimators get the detection with its four corners on one
  line (a collapsed region);
* ``pose_flip``: the estimate is mirrored through the camera (the planar-pose ambiguity's
  far solution: the target on the other side, heading turned by 180 deg).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np
from eaglemission.lab.faults.schedule import ActiveFaults

from eaglemission.interfaces import CameraView
from eaglemission.types import Detection, DetectionResult, EstimationFailed, Frame, TargetEstimate


class InjectedDetectorError(RuntimeError):
    """The exception a ``detector_exception`` fault raises from ``detect``."""


class FaultyDetector:
    """A detector with injected faults around ``inner``."""

    def __init__(self, inner: Any, faults: ActiveFaults, clock: Any) -> None:
        self.inner, self.faults, self.clock = inner, faults, clock

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def reset(self) -> None:
        self.inner.reset()

    def detect(self, frame: Frame, prior: Any = None) -> DetectionResult:
        now = self.clock.now_ns()
        if self.faults.active("detector_exception", now):
            raise InjectedDetectorError("detector failed (injected fault)")
        slow = self.faults.active("slow_frame", now)
        if slow is not None:
            time.sleep(slow.value)
        result: DetectionResult = self.inner.detect(frame, prior)
        if self.faults.active("nan_map", now):
            nan = np.full_like(result.saliency, np.nan)
            dets = tuple(Detection(d.score, (np.nan, np.nan), np.full((4, 2), np.nan),
                                   d.size_px, d.angle_deg, d.area_px, d.camera_id)
                         for d in result.detections)
            result = replace(result, saliency=nan, detections=dets)
        return result


class FaultyEstimator:
    """An estimator with injected faults around ``inner`` (the fine and the coarse one)."""

    def __init__(self, inner: Any, faults: ActiveFaults, clock: Any) -> None:
        self.inner, self.faults, self.clock = inner, faults, clock

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def estimate(self, detection: Detection, view: CameraView
                 ) -> TargetEstimate | EstimationFailed:
        now = self.clock.now_ns()
        if self.faults.active("degenerate_corners", now):
            c = np.asarray(detection.corners_px, dtype=np.float64)
            a, b = c[0], c[2]
            line = np.array([a, a + (b - a) / 3, a + 2 * (b - a) / 3, b])
            detection = replace(detection, corners_px=line, size_px=(detection.size_px[0], 0.0),
                                area_px=0.0)
        try:
            est: TargetEstimate | EstimationFailed = self.inner.estimate(detection, view)
        except (ValueError, np.linalg.LinAlgError) as exc:  # misuse from degenerate input
            return EstimationFailed(f"degenerate corners: {exc}")
        if est and self.faults.active("pose_flip", now):
            assert isinstance(est, TargetEstimate)
            cam = np.asarray(view.vehicle.position_ned_m, dtype=np.float64)
            p = np.asarray(est.position_ned_m, dtype=np.float64)
            flipped = (float(2 * cam[0] - p[0]), float(2 * cam[1] - p[1]), float(p[2]))
            yaw = None if est.yaw_deg is None else (est.yaw_deg + 180.0) % 360.0
            est = replace(est, position_ned_m=flipped, yaw_deg=yaw)
        return est
