"""Spectral residual saliency (Hou & Zhang 2007), OpenCV contrib's implementation wrapped.

``cv2.saliency.StaticSaliencySpectralResidual`` works on a 64 x 64 grey thumbnail (log
amplitude spectrum minus its 3 x 3 local mean, back-transformed with the original phase,
squared, Gaussian-smoothed) and returns the map resized to the input size, min-max normalised
per frame. The map is therefore *relative*: every frame has a pixel at 1, so with the fixed
threshold SR always reports a region, also in an empty scene (docs/detectors.md, "No target").

References
----------
X. Hou, L. Zhang, "Saliency detection: a spectral residual approach", CVPR 2007,
DOI 10.1109/CVPR.2007.383267 (ref. [34] of the eagle-eye paper).
"""

from __future__ import annotations

from typing import Any, ClassVar

import cv2
import numpy as np
from eaglemission.detectors.base import DetectorConfig, SaliencyDetector, shrink, to_frame_size
from pydantic import Field

from eaglemission.types import Frame, Saliency


class SpectralResidualConfig(DetectorConfig):
    """Params of ``sr``."""

    thumbnail_px: int = Field(64, ge=16, le=512, description="side of the square thumbnail")
    downscale: int = Field(1, ge=1, le=16, description="process the frame at 1/k resolution")


class SpectralResidualDetector(SaliencyDetector):
    """Spectral residual (Hou & Zhang 2007) through cv2.saliency."""

    Config: ClassVar[type[SpectralResidualConfig]] = SpectralResidualConfig
    description: ClassVar[str] = "spectral residual saliency (Hou & Zhang 2007), OpenCV contrib"

    def __init__(self, config: SpectralResidualConfig | None = None, **context: Any) -> None:
        super().__init__(config, **context)
        contrib: Any = cv2  # cv2.saliency (opencv-contrib) is missing from OpenCV's stubs
        self._sr = contrib.saliency.StaticSaliencySpectralResidual_create()
        self._sr.setImageWidth(self.config.thumbnail_px)
        self._sr.setImageHeight(self.config.thumbnail_px)

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        small = shrink(image, self.config.downscale)
        ok, sal = self._sr.computeSaliency(small)
        if not ok:
            return np.zeros(image.shape[:2], np.float32)
        return to_frame_size(sal, image.shape[:2])
