"""Maximum symmetric surround saliency (Achanta & Süsstrunk 2010), with integral images.

For a pixel (x, y) of a W x H image the surround is the largest window centred on it that fits
the image: half-widths ``x0 = min(x, W - 1 - x)``, ``y0 = min(y, H - 1 - y)`` (Eq. (4) of the
reference, 0-based). ``S(x, y) = || I_mu(x, y) - I_f(x, y) ||`` in CIE Lab (Eq. (3)), with
``I_mu`` the mean of the window, computed with an integral image, and ``I_f`` the Gaussian-blurred
image. Scale of the map as for ``ft`` (fixed Lab full scale by default, or min-max).

References
----------
R. Achanta, S. Süsstrunk, "Saliency detection using maximum symmetric surround", ICIP 2010,
DOI 10.1109/ICIP.2010.5652636 (ref. [31] of the eagle-eye paper).
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import cv2
import numpy as np
from eaglemission.detectors.base import DetectorConfig, SaliencyDetector, shrink, to_frame_size
from eaglemission.detectors.frequency_tuned import _LAB8_TO_LAB, scale_map
from pydantic import Field

from eaglemission.types import Frame, Saliency


def symmetric_surround_counts(n: int) -> np.ndarray:
    """Length of the symmetric surround of every index along an axis of ``n`` pixels.

    The window of index ``i`` is ``[i - r, i + r]`` with ``r = min(i, n - 1 - i)``: for
    ``i < ceil(n / 2)`` it is the prefix ``[0, 2i]``, above it the suffix ``[2i - n + 1, n - 1]``.
    """
    i = np.arange(n)
    return np.where(i < (n + 1) // 2, 2 * i + 1, 2 * n - 2 * i - 1)


def symmetric_surround_mean(img: np.ndarray) -> np.ndarray:
    """Mean of every pixel's maximum symmetric surround (Eq. (4) of Achanta 2010).

    One integral image; because every window is a prefix or a suffix along each axis, the four
    corner look-ups reduce to strided slices (no per-pixel gather).

    Parameters
    ----------
    img : ndarray of shape (H, W, C) or (H, W), float

    Returns
    -------
    ndarray of the same shape, float32
    """
    a = np.asarray(img, np.float32)
    squeeze = a.ndim == 2
    if squeeze:
        a = a[:, :, None]
    h, w, c = a.shape
    ii = cv2.integral(a, sdepth=cv2.CV_64F)
    if ii.ndim == 2:
        ii = ii[:, :, None]
    # Along y: row y2 minus row y1 of the integral image (prefix rows, then suffix rows).
    hl = (h + 1) // 2
    d = np.empty((h, w + 1, c), np.float64)
    np.subtract(ii[1 : 2 * hl : 2], ii[0:1], out=d[:hl])
    np.subtract(ii[h : h + 1], ii[2 * hl - h + 1 : h : 2], out=d[hl:])
    # Along x: the same on the columns of d.
    wl = (w + 1) // 2
    s = np.empty((h, w, c), np.float32)
    np.subtract(d[:, 1 : 2 * wl : 2], d[:, 0:1], out=s[:, :wl], casting="same_kind")
    np.subtract(d[:, w : w + 1], d[:, 2 * wl - w + 1 : w : 2], out=s[:, wl:], casting="same_kind")
    area = np.outer(symmetric_surround_counts(h), symmetric_surround_counts(w))
    s *= (1.0 / area).astype(np.float32)[:, :, None]
    return s[:, :, 0] if squeeze else s


class MSSConfig(DetectorConfig):
    """Params of ``mss``."""

    blur_sigma_px: float = Field(1.0, ge=0, le=20, description="Gaussian blur of I_f")
    normalization: Literal["fixed", "minmax"] = "fixed"
    full_scale_lab: float = Field(120.0, gt=0, description="Lab distance mapped to 1 (fixed)")
    downscale: int = Field(1, ge=1, le=16, description="process the frame at 1/k resolution")


class MaximumSymmetricSurroundDetector(SaliencyDetector):
    """Maximum symmetric surround saliency (Achanta & Süsstrunk 2010)."""

    Config: ClassVar[type[MSSConfig]] = MSSConfig
    description: ClassVar[str] = "maximum symmetric surround saliency (Achanta & Susstrunk 2010)"

    def __init__(self, config: MSSConfig | None = None, **context: Any) -> None:
        super().__init__(config, **context)

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        cfg = self.config
        small = shrink(image, cfg.downscale)
        lab8 = cv2.cvtColor(small, cv2.COLOR_BGR2Lab)
        sigma = cfg.blur_sigma_px / cfg.downscale
        blurred8 = cv2.GaussianBlur(lab8, (0, 0), sigma) if sigma > 0 else lab8
        # I_mu - I_f in CIE units (the 8-bit offsets cancel; only the L scale remains)
        diff = symmetric_surround_mean(lab8.astype(np.float32)) - blurred8.astype(np.float32)
        diff = cv2.transform(diff, _LAB8_TO_LAB[:, :3])
        d = cv2.sqrt(cv2.transform(diff * diff, np.ones((1, 3), np.float32)))
        return to_frame_size(scale_map(d, cfg.normalization, cfg.full_scale_lab), image.shape[:2])
