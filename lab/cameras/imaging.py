"""The synthetic camera's imaging effects after the scene is drawn (docs/simulation.md,
"Imaging effects"): motion blur from the camera's motion during the exposure, a white-balance
colour cast, Bayer mosaicing + demosaicing through the genicam driver's own conversion, and a
JPEG round trip. Pure functions of their inputs (no RNG).

The order in :meth:`SyntheticWorld.render <eaglemission.lab.world.render.SyntheticWorld.render>`
follows the light: blur (optics, during the exposure) -> exposure gain x white balance -> lens
distortion -> sensor noise -> Bayer colour filter and demosaicing -> JPEG (a recorded or
streamed frame).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
from eaglemission.drivers.cameras.genicam import to_bgr
from numpy.typing import NDArray

MIN_BLUR_PX = 0.5
"""Image motions shorter than this are not blurred (a box of 0.5 px moves an edge's profile by
at most a quarter of a pixel's contrast): most wide-camera frames cost nothing."""

_MAX_GROUP_PX = 8.0  # a direct (non-DFT) cv2.filter2D kernel is at most 11 x 11 (area < 130)
_FIXED_POINT = 64.0  # scale of the int16 sums of a long blur's pieces
_FAR_M = 1e4  # the optical axis above the horizon: the motion of a point at infinity

BAYER_PATTERNS = ("BayerRG", "BayerBG", "BayerGR", "BayerGB")
"""GenICam PFNC names: the colours of the top-left 2 x 2 cell read row by row (the Basler
daA1280-54uc delivers ``BayerRG8``)."""

_CELL = {"BayerRG": ("R", "G", "G", "B"), "BayerBG": ("B", "G", "G", "R"),
         "BayerGR": ("G", "R", "B", "G"), "BayerGB": ("G", "B", "R", "G")}
_CHANNEL = {"B": 0, "G": 1, "R": 2}


# ---------------------------------------------------------------------------------------------
# Motion blur
# ---------------------------------------------------------------------------------------------
def optical_axis_motion_px(K: NDArray[np.float64], R_on_mid: NDArray[np.float64],
                           C_mid: NDArray[np.float64], R_on_start: NDArray[np.float64],
                           C_start: NDArray[np.float64]) -> tuple[float, float]:
    """Image motion (du, dv) in pixels of the scene point on the principal-point pixel.

    The ray through the principal point of the camera at (``R_on_mid``, ``C_mid``) meets the
    ground (the plane d = 0) at a point X (a point 10 km away when the ray points at or above
    the horizon: the motion is then the rotation's alone); the result is where X appears in
    the mid camera minus where it appears in the start camera.

    Parameters
    ----------
    K : (3, 3) pinhole intrinsics (the true camera's)
    R_on_mid, R_on_start : (3, 3) NED -> optical rotations of the two poses
    C_mid, C_start : (3,) optical centres in NED, metres
    """
    cx, cy = float(K[0, 2]), float(K[1, 2])
    ray = R_on_mid.T @ np.linalg.solve(K, np.array([cx, cy, 1.0]))  # NED direction
    ray = ray / np.linalg.norm(ray)
    if ray[2] > 1e-6 and -C_mid[2] / ray[2] < _FAR_M:
        X = C_mid + ray * (-C_mid[2] / ray[2])
    else:
        X = C_mid + ray * _FAR_M
    x = K @ (R_on_start @ (X - C_start))
    if x[2] <= 1e-9:
        return (0.0, 0.0)
    return (cx - float(x[0] / x[2]), cy - float(x[1] / x[2]))


def motion_blur_kernel(du_px: float, dv_px: float) -> NDArray[np.float32]:
    """A linear motion-blur kernel: a segment from -(du, dv)/2 to +(du, dv)/2 about the kernel
    centre, sampled every quarter pixel and splatted bilinearly (sums to 1; symmetric, so
    correlation and convolution agree). Side ``2 ceil(L / 2) + 3`` for a length L."""
    L = math.hypot(du_px, dv_px)
    r = int(math.ceil(L / 2.0)) + 1
    k = np.zeros((2 * r + 1, 2 * r + 1), np.float64)
    for s in _samples(L):
        _splat(k, r + s * du_px, r + s * dv_px)
    return np.asarray(k / k.sum(), dtype=np.float32)


def _samples(length_px: float) -> NDArray[np.float64]:
    """Positions along the segment, as fractions -0.5..0.5 of it, every quarter pixel."""
    return np.linspace(-0.5, 0.5, max(2, int(math.ceil(4.0 * length_px)) + 1))


def _splat(k: NDArray[np.float64], x: float, y: float) -> None:
    """Add a unit sample at (x, y) = (col, row) to ``k``, bilinearly."""
    x0, y0 = math.floor(x), math.floor(y)
    fx, fy = x - x0, y - y0
    k[y0, x0] += (1 - fx) * (1 - fy)
    k[y0, x0 + 1] += fx * (1 - fy)
    k[y0 + 1, x0] += (1 - fx) * fy
    k[y0 + 1, x0 + 1] += fx * fy


def motion_blur(img: NDArray[np.uint8], du_px: float, dv_px: float) -> NDArray[np.uint8]:
    """``img`` smeared along the image motion (du, dv) of one exposure (a new array; ``img``
    itself when the motion is shorter than :data:`MIN_BLUR_PX`).

    Up to 8 px one ``cv2.filter2D`` with :func:`motion_blur_kernel`; longer segments are cut
    into pieces of at most 8 px, each filtered with its own small kernel from a shifted view
    of the reflected-border image and summed in float: the same kernel, without OpenCV's
    switch to a DFT for kernels of 13 x 13 and more (~90 ms at 1280 x 960)."""
    L = math.hypot(du_px, dv_px)
    if L < MIN_BLUR_PX:
        return img
    if L <= _MAX_GROUP_PX:
        return np.asarray(cv2.filter2D(img, -1, motion_blur_kernel(du_px, dv_px),
                                       borderType=cv2.BORDER_REFLECT), dtype=np.uint8)
    H, W = img.shape[:2]
    m = int(math.ceil(L / _MAX_GROUP_PX))
    s = _samples(L)  # the whole segment's samples, shared out between the pieces
    pad = int(math.ceil(L / 2.0)) + 8
    padded = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_REFLECT)
    # int16 sums of the pieces at x64 (<= 255 x 64 < 2^15): OpenCV filters 8U -> 16S directly
    # up to an 11 x 11 kernel (8U -> 32F would switch to a DFT above 7 x 7)
    acc = np.zeros(img.shape, np.int16)
    r = int(math.ceil(_MAX_GROUP_PX / 2.0)) + 1
    m_px = r + 1  # margin so the piece's own border handling stays outside the crop
    for g in np.array_split(s, m):
        mid = 0.5 * (g[0] + g[-1])
        ox, oy = round(mid * du_px), round(mid * dv_px)  # integer shift of this piece
        k = np.zeros((2 * r + 1, 2 * r + 1), np.float64)
        for sv in g:
            _splat(k, r + sv * du_px - ox, r + sv * dv_px - oy)
        k *= _FIXED_POINT / len(s)
        view = padded[pad + oy - m_px:pad + oy + H + m_px, pad + ox - m_px:pad + ox + W + m_px]
        part = cv2.filter2D(view, cv2.CV_16S, k.astype(np.float32),
                            borderType=cv2.BORDER_REFLECT)
        cv2.add(acc, part[m_px:m_px + H, m_px:m_px + W], dst=acc)
    return np.asarray(cv2.convertScaleAbs(acc, alpha=1.0 / _FIXED_POINT), dtype=np.uint8)


# ---------------------------------------------------------------------------------------------
# White balance and exposure
# ---------------------------------------------------------------------------------------------
def colour_gain_lut(gains_bgr: Sequence[float]) -> NDArray[np.uint8]:
    """A (256, 1, 3) ``cv2.LUT`` table multiplying channel c by ``gains_bgr[c]`` (rounded,
    saturated at 255)."""
    v = np.arange(256, dtype=np.float64)[:, None] * np.asarray(gains_bgr, np.float64)[None, :]
    return np.clip(np.floor(v + 0.5), 0, 255).astype(np.uint8).reshape(256, 1, 3)


def apply_colour_gains(img: NDArray[np.uint8], gains_bgr: Sequence[float]) -> None:
    """In place: channel c x ``gains_bgr[c]`` (exposure gain x white-balance error)."""
    cv2.LUT(img, colour_gain_lut(gains_bgr), dst=img)


# ---------------------------------------------------------------------------------------------
# Bayer colour filter array
# ---------------------------------------------------------------------------------------------
def bayer_mosaic(img: NDArray[np.uint8], pattern: str = "BayerRG") -> NDArray[np.uint8]:
    """The raw single-channel frame a sensor with colour filter ``pattern`` (GenICam name)
    records of the BGR image ``img``: each pixel keeps the one channel its filter passes."""
    if pattern not in _CELL:
        raise ValueError(f"pattern: must be one of {', '.join(BAYER_PATTERNS)}, got {pattern!r}")
    H, W = img.shape[:2]
    raw = np.empty((H, W), np.uint8)
    for (dy, dx), colour in zip(((0, 0), (0, 1), (1, 0), (1, 1)), _CELL[pattern]):
        raw[dy::2, dx::2] = img[dy::2, dx::2, _CHANNEL[colour]]
    return raw


def bayer_round_trip(img: NDArray[np.uint8], pattern: str = "BayerRG") -> NDArray[np.uint8]:
    """``img`` through the colour filter and back: mosaiced to ``pattern`` and demosaiced by
    the genicam driver's own conversion (:func:`~eaglemission.drivers.cameras.genicam.to_bgr`,
    OpenCV's bilinear demosaicing), so edges get the same colour fringes as a real frame."""
    H, W = img.shape[:2]
    return to_bgr(bayer_mosaic(img, pattern), W, H, f"{pattern}8")


# ---------------------------------------------------------------------------------------------
# JPEG
# ---------------------------------------------------------------------------------------------
def jpeg_round_trip(img: NDArray[np.uint8], quality: int) -> NDArray[np.uint8]:
    """``img`` encoded as JPEG at ``quality`` (1-100, OpenCV's libjpeg, 4:2:0 chroma) and
    decoded again, as a recorded (``run --record``) or streamed frame is."""
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"img: OpenCV could not encode a {img.shape} {img.dtype} image as JPEG")
    return np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR), dtype=np.uint8)
