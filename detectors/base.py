"""Template for saliency detectors: frame validation, then ``saliency()``, then regions.

Subclasses implement ``_saliency(image, frame) -> float32 (H, W) in [0, 1]`` and, when they keep
temporal state, ``_reset()``. ``detect`` validates the frame (dtype, shape, channels, size),
resets on a resolution change, and hands the map to :func:`regions.find_regions`.

Context: ``cls(config=..., **context)``; every detector accepts and ignores the keys it does not
use (``camera_id`` from the runner, ...). ``saliency_map(frame)`` is the map alone (no regions),
for a stage that combines maps (the appearance prior, :mod:`eaglemission.perception.prior`).
"""

from __future__ import annotations

from typing import Any, ClassVar

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.errors import InputError
from eaglemission.perception.regions import RegionsConfig, find_regions
from eaglemission.types import DetectionResult, Frame, Saliency, TargetPrior


class DetectorConfig(BaseModel):
    """Base of every detector's params; ``regions`` configures thresholding and filtering."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    regions: RegionsConfig = Field(default_factory=RegionsConfig)


class SaliencyDetector:
    """Base class of the built-in detectors (a template method, aerostack2 style)."""

    Config: ClassVar[type[BaseModel]] = DetectorConfig
    description: ClassVar[str] = ""

    def __init__(self, config: BaseModel | None = None, **context: Any) -> None:
        self.config: Any = config if config is not None else self.Config()
        self._shape: tuple[int, int] | None = None

    # -- to implement ---------------------------------------------------------------------------
    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        raise NotImplementedError

    def _reset(self) -> None:
        """Drop temporal state (override when there is any)."""

    # -- public ---------------------------------------------------------------------------------
    def reset(self) -> None:
        self._shape = None
        self._reset()

    def saliency(self, frame: Frame) -> Saliency:
        image = self._frame_image(frame)
        shape = (image.shape[0], image.shape[1])
        sal = self._saliency(image, frame)
        if sal.shape != shape or sal.dtype != np.float32:
            raise RuntimeError(
                f"{type(self).__name__}._saliency returned {sal.dtype} {sal.shape}, "
                f"expected float32 {shape}")
        return sal

    def saliency_map(self, frame: Frame) -> Saliency:
        """The map alone, at the detector's processing resolution (here: the frame's)."""
        return self.saliency(frame)

    def _frame_image(self, frame: Frame) -> np.ndarray:
        """The frame's validated image; a change of resolution drops the temporal state."""
        image = validate_image(frame.image)
        shape = (image.shape[0], image.shape[1])
        if self._shape is not None and shape != self._shape:
            self._reset()  # resolution change: temporal state no longer applies
        self._shape = shape
        return image

    def detect(self, frame: Frame, prior: TargetPrior | None = None) -> DetectionResult:
        sal = self.saliency(frame)
        regions_cfg = getattr(self.config, "regions", None) or RegionsConfig()
        detections, threshold = find_regions(sal, regions_cfg, prior, camera_id=frame.camera_id)
        return DetectionResult(sal, detections, frame.timestamp_ns, frame.camera_id, frame.seq,
                               threshold)


def shrink(image: np.ndarray, factor: int) -> np.ndarray:
    """``image`` at 1/``factor`` resolution (area averaging); ``factor`` 1 returns it unchanged.

    Used by detectors that offer ``downscale`` (process at 1/k resolution, map upsampled).
    """
    if factor <= 1:
        return image
    h, w = image.shape[:2]
    size = (max(1, round(w / factor)), max(1, round(h / factor)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def to_frame_size(sal: np.ndarray, shape: tuple[int, int]) -> Saliency:
    """A map resized (bilinear) to ``shape`` = (H, W), as float32 clipped to [0, 1]."""
    out: NDArray[np.float32] = np.asarray(sal, dtype=np.float32)
    if out.shape[:2] != shape:
        out = np.asarray(cv2.resize(out, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR),
                         dtype=np.float32)
    return np.clip(out, 0.0, 1.0, out=out if out.flags.writeable else None)


def validate_image(image: Any) -> np.ndarray:
    """Accept (H, W, 3) BGR or (H, W) grey uint8 with H, W >= 8; grey becomes 3-channel."""
    if not isinstance(image, np.ndarray):
        raise InputError(f"image: must be a numpy array, got {type(image).__name__}")
    img: np.ndarray = image
    if img.dtype != np.uint8:
        raise InputError(f"image: must be uint8 (8-bit BGR or grey), got {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"image: must be (H, W, 3) BGR or (H, W) grey, got shape {img.shape}")
    if img.shape[0] < 8 or img.shape[1] < 8:
        raise InputError(f"image: must be at least 8x8 pixels, got {img.shape[1]}x{img.shape[0]}")
    return img
