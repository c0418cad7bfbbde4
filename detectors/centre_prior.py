"""A fixed centred Gaussian, the same map for every frame: the floor a detector must beat.

DAVIS-style footage is framed on its subject, so "the centre is salient" already scores well
(../shared/notes/dtdmi.md). ``S(u, v) = exp(-((u - cx)^2 / (2 sx^2) + (v - cy)^2 / (2 sy^2)))``
with ``sx = sigma_fraction * W``, ``sy = sigma_fraction * H`` and the centre ``((W-1)/2, (H-1)/2)``.
It ignores the image, so it also "detects" its centre blob in every frame.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from eaglemission.detectors.base import DetectorConfig, SaliencyDetector
from pydantic import Field

from eaglemission.types import Frame, Saliency


def centre_gaussian(height_px: int, width_px: int, sigma_fraction: float = 0.25) -> Saliency:
    """The centred Gaussian map, float32 (H, W), peak 1 at the image centre."""
    v = (np.arange(height_px, dtype=np.float64) - (height_px - 1) / 2.0) / (sigma_fraction * height_px)
    u = (np.arange(width_px, dtype=np.float64) - (width_px - 1) / 2.0) / (sigma_fraction * width_px)
    return np.exp(-0.5 * (v[:, None] ** 2 + u[None, :] ** 2)).astype(np.float32)


class CentrePriorConfig(DetectorConfig):
    """Params of ``centre_prior``."""

    sigma_fraction: float = Field(0.25, gt=0, le=10, description="sigma as a fraction of H and W")


class CentrePriorDetector(SaliencyDetector):
    """Fixed centred Gaussian (sigma 0.25 H, 0.25 W): the baseline floor."""

    Config: ClassVar[type[CentrePriorConfig]] = CentrePriorConfig
    description: ClassVar[str] = "fixed centred Gaussian (sigma 0.25 H, 0.25 W): baseline floor"

    def __init__(self, config: CentrePriorConfig | None = None, **context: Any) -> None:
        super().__init__(config, **context)
        self._cache: tuple[tuple[int, int], Saliency] | None = None

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        shape = (image.shape[0], image.shape[1])
        if self._cache is None or self._cache[0] != shape:
            self._cache = (shape, centre_gaussian(*shape, self.config.sigma_fraction))
        return self._cache[1].copy()
