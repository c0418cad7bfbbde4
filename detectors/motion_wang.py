"""Motion saliency by OpenCV contrib's ``MotionSaliencyBinWangApr2014``, wrapped.

A per-pixel background model (Wang & Dudek 2014) on the grey image; its map is binary
(1 = foreground). It assumes a static camera and spends its first ~50 frames learning: during
that phase OpenCV marks *every* pixel as foreground. A map with no background pixel carries no
information, so the wrapper reports it as an empty map (all zeros) rather than a full-frame
"detection". The model is created with ``setImagesize`` + ``init`` at the first frame and again
after ``reset()`` or a resolution change (the base class calls ``_reset``).

References
----------
B. Wang, P. Dudek, "A fast self-tuning background subtraction algorithm", CVPR Workshops 2014,
DOI 10.1109/CVPRW.2014.64.
"""

from __future__ import annotations

from typing import Any, ClassVar

import cv2
import numpy as np
from eaglemission.detectors.base import DetectorConfig, SaliencyDetector, shrink, to_frame_size
from pydantic import Field

from eaglemission.types import Frame, Saliency


class MotionWangConfig(DetectorConfig):
    """Params of ``motion_wang``."""

    downscale: int = Field(1, ge=1, le=16, description="process the frame at 1/k resolution")
    blur_sigma_px: float = Field(0.0, ge=0, le=50, description="smooth the binary map (0: off)")


class MotionWangDetector(SaliencyDetector):
    """OpenCV contrib MotionSaliencyBinWangApr2014 (static-camera background model)."""

    Config: ClassVar[type[MotionWangConfig]] = MotionWangConfig
    description: ClassVar[str] = "OpenCV contrib MotionSaliencyBinWangApr2014 (background model)"

    def __init__(self, config: MotionWangConfig | None = None, **context: Any) -> None:
        super().__init__(config, **context)
        self._model: Any = None
        self._model_size: tuple[int, int] | None = None

    def _reset(self) -> None:
        self._model = None
        self._model_size = None

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        cfg = self.config
        grey = cv2.cvtColor(shrink(image, cfg.downscale), cv2.COLOR_BGR2GRAY)
        size = (grey.shape[1], grey.shape[0])
        if self._model is None or self._model_size != size:
            contrib: Any = cv2  # cv2.saliency (opencv-contrib) is missing from OpenCV's stubs
            self._model = contrib.saliency.MotionSaliencyBinWangApr2014_create()
            self._model.setImagesize(*size)
            if not self._model.init():
                raise RuntimeError("MotionSaliencyBinWangApr2014.init() failed")
            self._model_size = size
        ok, binary = self._model.computeSaliency(grey)
        if not ok or cv2.countNonZero(binary) == binary.size:
            return np.zeros(image.shape[:2], np.float32)  # learning phase: no information
        sal = binary.astype(np.float32)
        if cfg.blur_sigma_px > 0:
            sal = cv2.GaussianBlur(sal, (0, 0), cfg.blur_sigma_px / cfg.downscale)
        return to_frame_size(sal, image.shape[:2])
