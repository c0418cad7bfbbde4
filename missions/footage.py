"""The mission's perception on footage: one camera's frames through exactly what the mission
runs on a camera (detect, acquire and keep, choose the target: :mod:`.perception`), without a
vehicle, a calibration or a pose. ``eaglemission detect`` and ``eaglemission bench --mission``
use it, so anyone can score the mission's perception on their own footage.

With no vehicle state nothing is measured in 3-D: the size plausibility and the gate around a
predicted pixel drop out (the keeper's box is where to look), and the pose stage is not asked.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.perception import Measurement, Perception, Request, Tools
from eaglemission.missions.target_state import PlaneState

from eaglemission import registry
from eaglemission.config import MissionFile
from eaglemission.geometry import CameraModel
from eaglemission.names import CAMERA_WIDE
from eaglemission.perception.appearance import TargetAppearance
from eaglemission.perception.keep import TargetKeeper
from eaglemission.types import DetectionResult, Frame


@dataclass(frozen=True)
class FootageOptions:
    """What to change of the mission file's perception for footage."""

    example_image: Any = None
    """The target's example image (BGR), over the mission file's ``target.appearance_image``
    (None: the mission file's, if any)."""
    without_image: bool = False
    """No example image at all (the detector and the target's colour alone)."""
    keep: bool = True
    """False: no keeper (the detector's choice on every frame)."""
    mission_colour: bool = True
    """Use the mission file's ``target.color_bgr``; False for footage of another target (its
    colour unknown)."""


class FootagePerception:
    """One camera's perception of a mission file, frame by frame (see the module docstring)."""

    def __init__(self, cfg: MissionFile, options: FootageOptions | None = None,
                 camera_id: str = CAMERA_WIDE) -> None:
        opt = options or FootageOptions()
        self.camera_id = camera_id
        target = cfg.target
        if opt.without_image:
            image = None
        elif opt.example_image is not None:
            image = opt.example_image
        else:
            image = TargetAppearance.of_target(target, cfg.appearance).image \
                if target.appearance_image else None
        colour = target.color_bgr if opt.mission_colour else None
        self.appearance = TargetAppearance(image=image, colour_bgr=colour,
                                           colour=cfg.appearance.colour,
                                           example=cfg.appearance.example)
        detector = registry.load("detectors", cfg.detector.type, cfg.detector.params,
                                 camera_id=camera_id)
        self.detector = self.appearance.with_prior(detector, cfg.appearance.prior)
        self.keeper: TargetKeeper | None = None
        if opt.keep and cfg.tracker is not None:
            self.keeper = TargetKeeper(
                registry.load("trackers", cfg.tracker.type, cfg.tracker.params,
                              camera_id=camera_id), cfg.tracker.keep)
        params = ApproachConfig.of(cfg).perception
        self.perception = Perception(params, target, thumbnails=False)
        self._seen = _LastResult(self.detector)
        self.tools = Tools(self._seen, _NoEstimator(), _NoEstimator(), None,
                           self.appearance if self.appearance.known else None, self.keeper)
        self._model: CameraModel | None = None

    @property
    def last_result(self) -> DetectionResult | None:
        """The detector's result on the last frame (None: it did not run on it)."""
        return self._seen.last

    def process(self, frame: Frame) -> Measurement:
        """The frame's measurement: ``detection`` the target (``kept``: confirmed) or a
        candidate."""
        model = self._model_for(np.asarray(frame.image))
        req = Request(frame, model, None, None, None, False, None, PlaneState(0.0, 1.0))
        self._seen.last = None
        return self.perception.perceive(req, self.tools)

    def _model_for(self, image: np.ndarray) -> CameraModel:
        h, w = image.shape[:2]
        if self._model is None or (self._model.width_px, self._model.height_px) != (w, h):
            f = float(max(w, h))  # nothing is measured in 3-D: any pinhole will do
            k = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
            self._model = CameraModel(self.camera_id, w, h, k)
        return self._model


class _LastResult:
    """The detector, keeping its last result for the caller (overlays, the detections' file)."""

    def __init__(self, detector: Any) -> None:
        self.detector = detector
        self.last: DetectionResult | None = None

    def detect(self, frame: Frame, prior: Any = None) -> DetectionResult:
        self.last = self.detector.detect(frame, prior)
        return self.last

    def reset(self) -> None:
        self.detector.reset()


class _NoEstimator:
    """Footage has no pose: the pose stage is never asked (``Request.estimator`` None)."""

    def estimate(self, *_args: Any, **_kwargs: Any) -> Any:
        raise RuntimeError("footage perception measures no pose")
