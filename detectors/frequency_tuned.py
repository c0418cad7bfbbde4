"""Frequency-tuned saliency (Achanta et al. 2009), in numpy/OpenCV.

``S(x) = || I_mu - I_blur(x) ||`` in CIE Lab (Eq. (3) of the reference): the distance of every
pixel of a Gaussian-blurred image to the image's mean colour. The map keeps an absolute scale:
the Lab distance divided by ``full_scale_lab`` and clipped to 1 (``normalization: fixed``, the
default, so an even scene stays dark), or per-frame min-max (``minmax``, as in the reference).

References
----------
R. Achanta, S. Hemami, F. Estrada, S. Süsstrunk, "Frequency-tuned salient region detection",
CVPR 2009, DOI 10.1109/CVPR.2009.5206596 (ref. [44] of the eagle-eye paper).
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import cv2
import numpy as np
from eaglemission.detectors.base import DetectorConfig, SaliencyDetector, shrink, to_frame_size
from pydantic import Field

from eaglemission.types import Frame, Saliency

# 8-bit Lab (L * 255/100, a + 128, b + 128) back to CIE units.
_LAB8_TO_LAB = np.array([[100.0 / 255.0, 0, 0, 0], [0, 1, 0, -128.0], [0, 0, 1, -128.0]],
                        np.float32)


def lab_float(image_bgr: np.ndarray) -> np.ndarray:
    """BGR uint8 -> CIE Lab float32 (L in 0..100, a and b about -128..127).

    Through OpenCV's 8-bit conversion (a table look-up, ~1.5x faster than the float path at
    1280x960); quantisation steps 0.39 in L and 1 in a, b, far below what saliency resolves.
    """
    lab8 = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2Lab)
    return cv2.transform(lab8.astype(np.float32), _LAB8_TO_LAB)


def frequency_tuned_distance(lab: np.ndarray, blur_sigma_px: float) -> np.ndarray:
    """Eq. (3) of Achanta 2009: Euclidean Lab distance of the blurred image to its mean colour."""
    blurred = cv2.GaussianBlur(lab, (0, 0), blur_sigma_px) if blur_sigma_px > 0 else lab
    mean = np.asarray(cv2.mean(lab)[:3], np.float32)
    diff = blurred - mean
    return cv2.sqrt(cv2.transform(diff * diff, np.ones((1, 3), np.float32)))


def frequency_tuned_map(image_bgr: np.ndarray, blur_sigma_px: float) -> np.ndarray:
    """:func:`frequency_tuned_distance` of a BGR frame, fast path: the 8-bit Lab image is
    blurred in 8 bits and the mean subtraction folded into the unit conversion (equal to the
    float path within the 8-bit rounding, < 1 Lab unit; 1.7x faster at 1280x960)."""
    lab8 = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2Lab)
    mean8 = np.asarray(cv2.mean(lab8)[:3], np.float32)
    if blur_sigma_px > 0:
        lab8 = cv2.GaussianBlur(lab8, (0, 0), blur_sigma_px)
    m = _LAB8_TO_LAB.copy()
    m[:, 3] = -(_LAB8_TO_LAB[:, :3] @ mean8)  # (x8 - mean8) in CIE units
    diff = cv2.transform(lab8.astype(np.float32), m)
    return cv2.sqrt(cv2.transform(cv2.multiply(diff, diff), np.ones((1, 3), np.float32)))


class LabDistanceConfig(DetectorConfig):
    """Params of the detectors whose map is a Lab colour distance (``ft``, ``mss``)."""

    blur_sigma_px: float = Field(1.0, ge=0, le=20, description="Gaussian blur (the reference's 5x5 binomial ~ sigma 1)")
    normalization: Literal["fixed", "minmax"] = "fixed"
    full_scale_lab: float = Field(120.0, gt=0, description="Lab distance mapped to 1 (fixed)")
    downscale: int = Field(1, ge=1, le=16, description="process the frame at 1/k resolution")


class FrequencyTunedConfig(LabDistanceConfig):
    """Params of ``ft``."""


class FrequencyTunedDetector(SaliencyDetector):
    """Frequency-tuned saliency (Achanta 2009)."""

    Config: ClassVar[type[FrequencyTunedConfig]] = FrequencyTunedConfig
    description: ClassVar[str] = "frequency-tuned saliency (Achanta 2009): Lab distance to the mean colour"

    def __init__(self, config: FrequencyTunedConfig | None = None, **context: Any) -> None:
        super().__init__(config, **context)

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        cfg = self.config
        small = shrink(image, cfg.downscale)
        d = frequency_tuned_map(small, cfg.blur_sigma_px / cfg.downscale)
        return to_frame_size(scale_map(d, cfg.normalization, cfg.full_scale_lab), image.shape[:2])


def scale_map(d: np.ndarray, normalization: str, full_scale: float) -> np.ndarray:
    """Distance map -> [0, 1]: ``d / full_scale`` clipped (fixed) or per-frame min-max."""
    if normalization == "minmax":
        lo, hi = cv2.minMaxLoc(d)[:2]
        return (d - lo) * np.float32(1.0 / (hi - lo)) if hi > lo else np.zeros_like(d)
    return np.minimum(d * np.float32(1.0 / full_scale), np.float32(1.0))
