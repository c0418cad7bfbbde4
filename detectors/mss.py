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

from typing import Any, ClassVar

import cv2
import numpy as np
from eaglemission.detectors.base import SaliencyDetector, shrink, to_frame_size
from eaglemission.detectors.frequency_tuned import _LAB8_TO_LAB, LabDistanceConfig, scale_map
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


def _compile_distance_kernel() -> Any:
    """The fused MSS kernel (numba, cached on disk), or None when numba is not importable."""
    try:
        from numba import njit
    except ImportError:  # pragma: no cover - numba is a dependency
        return None

    @njit(cache=True, nogil=True, fastmath=True)
    def mss_distance(ii: np.ndarray, blurred8: np.ndarray, inv_y: np.ndarray,
                     inv_x: np.ndarray, to_lab: np.ndarray, scale: float, cap: float
                     ) -> np.ndarray:
        # Per pixel, from the exact integer integral image ``ii`` (H+1, W+1, 3): the
        # symmetric-surround mean (Eq. (4) of Achanta 2010), minus the blurred pixel, in CIE
        # units, its L2 norm, times ``scale``, at most ``cap``. inv_y / inv_x: 1 / (window
        # length) along each axis. Per row, the window's rows are reduced first (prefix sums
        # along x of the row band, exact in float64), then every pixel is a difference of two
        # columns of that: the left half a prefix [0, 2x], the right half a suffix.
        h, w = blurred8.shape[0], blurred8.shape[1]
        out = np.empty((h, w), np.float32)
        band = np.empty((w + 1, 3), np.float64)
        l00, l01, l02 = to_lab[0, 0], to_lab[0, 1], to_lab[0, 2]
        l10, l11, l12 = to_lab[1, 0], to_lab[1, 1], to_lab[1, 2]
        l20, l21, l22 = to_lab[2, 0], to_lab[2, 1], to_lab[2, 2]
        s32 = np.float32(scale)
        c32 = np.float32(cap)
        wl = (w + 1) // 2
        for y in range(h):
            ry = min(y, h - 1 - y)
            y1 = y - ry
            y2 = y + ry + 1
            for x in range(w + 1):
                for k in range(3):
                    band[x, k] = np.float64(ii[y2, x, k] - ii[y1, x, k])
            iy = inv_y[y]
            for x in range(w):
                if x < wl:
                    s0 = band[2 * x + 1, 0]  # band[0] is 0: the integral's first column
                    s1 = band[2 * x + 1, 1]
                    s2 = band[2 * x + 1, 2]
                else:
                    x1 = 2 * x - w + 1
                    s0 = band[w, 0] - band[x1, 0]
                    s1 = band[w, 1] - band[x1, 1]
                    s2 = band[w, 2] - band[x1, 2]
                inv_area = iy * inv_x[x]
                d0 = np.float32(s0 * inv_area) - np.float32(blurred8[y, x, 0])
                d1 = np.float32(s1 * inv_area) - np.float32(blurred8[y, x, 1])
                d2 = np.float32(s2 * inv_area) - np.float32(blurred8[y, x, 2])
                v0 = l00 * d0 + l01 * d1 + l02 * d2
                v1 = l10 * d0 + l11 * d1 + l12 * d2
                v2 = l20 * d0 + l21 * d1 + l22 * d2
                d = np.float32(np.sqrt(v0 * v0 + v1 * v1 + v2 * v2))
                out[y, x] = min(d * s32, c32)
        return out

    return mss_distance


_KERNEL: list[Any] = []


def _distance_kernel() -> Any:
    if not _KERNEL:
        _KERNEL.append(_compile_distance_kernel())
    return _KERNEL[0]


def mss_distance(lab8: np.ndarray, blurred8: np.ndarray, *, full_scale_lab: float | None = None,
                 backend: str = "numba") -> np.ndarray:
    """``|| I_mu - I_f ||`` in CIE Lab units (Eq. (3) of Achanta 2010) from the 8-bit Lab image
    and its blurred copy (both (H, W, 3) uint8); float32 (H, W).

    ``backend="numba"`` runs one fused compiled pass (integer integral image, surround mean,
    difference, Lab scaling, norm: ~4x faster than the numpy path at 640x480, equal within
    float32 rounding); ``"numpy"`` is the reference implementation with OpenCV/numpy.
    With ``full_scale_lab`` the distance is divided by it and clipped to 1 (the ``fixed``
    normalisation of :func:`scale_map`, fused into the same pass).
    """
    # fixed normalisation: d * float32(1 / full_scale) clipped to 1; else d (x 1, no cap)
    scale, cap = (1.0, 3.0e38) if full_scale_lab is None else (1.0 / float(full_scale_lab), 1.0)
    kernel = _distance_kernel() if backend == "numba" else None
    if kernel is not None:
        h, w = lab8.shape[:2]
        # exact integer sums: 32-bit while 255 * H * W fits, else 64-bit
        depth = cv2.CV_32S if 255 * h * w < 2**31 else cv2.CV_64F
        ii = cv2.integral(lab8, sdepth=depth)
        if depth == cv2.CV_64F:
            ii = ii.astype(np.int64)
        inv_y = 1.0 / symmetric_surround_counts(h).astype(np.float64)
        inv_x = 1.0 / symmetric_surround_counts(w).astype(np.float64)
        dist: np.ndarray = kernel(ii.reshape(h + 1, w + 1, 3), np.ascontiguousarray(blurred8),
                                  inv_y, inv_x,
                                  np.ascontiguousarray(_LAB8_TO_LAB[:, :3], dtype=np.float64),
                                  scale, cap)
        return dist
    # I_mu - I_f in CIE units (the 8-bit offsets cancel; only the L scale remains)
    diff = symmetric_surround_mean(lab8.astype(np.float32)) - blurred8.astype(np.float32)
    diff = cv2.transform(diff, _LAB8_TO_LAB[:, :3])
    d = cv2.sqrt(cv2.transform(diff * diff, np.ones((1, 3), np.float32)))
    return d if full_scale_lab is None else scale_map(d, "fixed", full_scale_lab)


class MSSConfig(LabDistanceConfig):
    """Params of ``mss``."""

    blur_sigma_px: float = Field(1.0, ge=0, le=20, description="Gaussian blur of I_f")


class MaximumSymmetricSurroundDetector(SaliencyDetector):
    """Maximum symmetric surround saliency (Achanta & Süsstrunk 2010)."""

    Config: ClassVar[type[MSSConfig]] = MSSConfig
    description: ClassVar[str] = "maximum symmetric surround saliency (Achanta & Susstrunk 2010)"

    def __init__(self, config: MSSConfig | None = None, **context: Any) -> None:
        super().__init__(config, **context)
        # Load (or, the first time ever, compile) the kernel now, not inside the first frame.
        tiny = np.zeros((8, 8, 3), np.uint8)
        mss_distance(tiny, tiny)

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        cfg = self.config
        small = shrink(image, cfg.downscale)
        lab8 = cv2.cvtColor(small, cv2.COLOR_BGR2Lab)
        sigma = cfg.blur_sigma_px / cfg.downscale
        blurred8 = cv2.GaussianBlur(lab8, (0, 0), sigma) if sigma > 0 else lab8
        if cfg.normalization == "fixed":  # scaled and clipped inside the same pass
            sal = mss_distance(lab8, blurred8, full_scale_lab=cfg.full_scale_lab)
        else:
            sal = scale_map(mss_distance(lab8, blurred8), cfg.normalization, cfg.full_scale_lab)
        return to_frame_size(sal, image.shape[:2])
