"""Global image motion between consecutive frames, to align the delay units (ego-motion).

The delay units hold the previous frames' gradient responses in image coordinates; when the
camera moves, the static world moves in the image and the correlators of Eq. (10) respond to it.
Warping the state by the estimated frame-to-frame motion before Eq. (10) cancels that response
for the background (a plane, or a distant scene) and keeps it for independently moving targets.

Estimators work on a small grey copy (``width_px`` wide) and return a 3x3 homography mapping
previous-frame pixel coordinates to current-frame pixel coordinates at full resolution:

- ``phase``: translation by phase correlation (``cv2.phaseCorrelate`` with a Hanning window);
- ``homography``: Shi-Tomasi corners tracked by pyramidal Lucas-Kanade, RANSAC homography.

Either returns the identity when the estimate is unreliable (low phase-correlation peak, too
few tracked points or inliers): no compensation is safer than a wrong one.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

Mat3 = NDArray[np.float64]


def scale_matrix(s: float) -> Mat3:
    """Pixel-centre mapping from full resolution to a resize by ``s`` (``x' = (x + .5) s - .5``)."""
    return np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, s, 0.5 * s - 0.5], [0.0, 0.0, 1.0]])


def homography_at_scale(h_full: Mat3, s: float) -> Mat3:
    """The same image motion expressed in the pixel coordinates of a resize by ``s``."""
    sm = scale_matrix(s)
    return sm @ h_full @ np.linalg.inv(sm)


def phase_motion(prev: NDArray[np.float32], cur: NDArray[np.float32], s: float,
                 min_response: float = 0.05) -> Mat3:
    """Translation of ``cur`` relative to ``prev`` (small grey images at scale ``s``)."""
    win = _hanning(prev.shape)
    (dx, dy), response = cv2.phaseCorrelate(prev, cur, win)
    if not np.isfinite(dx) or response < min_response:
        return np.eye(3)
    return np.array([[1.0, 0.0, dx / s], [0.0, 1.0, dy / s], [0.0, 0.0, 1.0]])


_HANN: dict[tuple[int, int], NDArray[np.float32]] = {}


def _hanning(shape: tuple[int, int]) -> NDArray[np.float32]:
    key = (int(shape[0]), int(shape[1]))
    if key not in _HANN:
        _HANN[key] = np.asarray(cv2.createHanningWindow((key[1], key[0]), cv2.CV_32F),
                                dtype=np.float32)
    return _HANN[key]


def homography_motion(prev: NDArray[np.float32], cur: NDArray[np.float32], s: float,
                      max_corners: int = 150, min_inliers: int = 12) -> Mat3:
    """RANSAC homography of tracked corners from ``prev`` to ``cur`` (small grey at scale ``s``)."""
    # Same contrast stretch for both images (LK compares grey levels), from the previous one.
    lo, hi = float(prev.min()), float(prev.max())
    k = 255.0 / (hi - lo) if hi > lo else 1.0
    p8 = np.clip((prev - lo) * k, 0, 255).astype(np.uint8)
    c8 = np.clip((cur - lo) * k, 0, 255).astype(np.uint8)
    pts = cv2.goodFeaturesToTrack(p8, max_corners, 0.01, 5)
    if pts is None or len(pts) < min_inliers:
        return np.eye(3)
    nxt, status, _ = cv2.calcOpticalFlowPyrLK(  # type: ignore[call-overload]  # stubs lack nextPts=None
        p8, c8, pts, None, winSize=(15, 15), maxLevel=2)
    ok = status.ravel() == 1
    if ok.sum() < min_inliers:
        return np.eye(3)
    hm, inl = cv2.findHomography(pts[ok], nxt[ok], cv2.RANSAC, 1.0)
    # Reject weak consensus (fewer than half of the tracks) and implausible frame-to-frame
    # motion (scale change beyond +-20 %): no compensation is safer than a wrong one.
    if hm is None or inl is None or int(inl.sum()) < max(min_inliers, 0.5 * ok.sum()):
        return np.eye(3)
    det2 = float(np.linalg.det(hm[:2, :2] / hm[2, 2]))
    if not 0.64 < det2 < 1.44:
        return np.eye(3)
    sm = scale_matrix(s)
    motion: Mat3 = np.linalg.inv(sm) @ hm @ sm
    return motion


def estimate_motion(method: str, prev: NDArray[np.float32], cur: NDArray[np.float32],
                    s: float) -> Mat3:
    """Dispatch on ``method`` in {"phase", "homography"}; identity for anything else."""
    if method == "phase":
        return phase_motion(prev, cur, s)
    if method == "homography":
        return homography_motion(prev, cur, s)
    return np.eye(3)


def shift_integer(plane: NDArray[np.float32], dx: int, dy: int,
                  out: NDArray[np.float32]) -> None:
    """``out[r + dy, c + dx] = plane[r, c]``, zeros where nothing maps (no interpolation)."""
    hh, ww = plane.shape
    out[...] = 0.0
    if abs(dx) >= ww or abs(dy) >= hh:
        return
    out[max(dy, 0):hh + min(dy, 0), max(dx, 0):ww + min(dx, 0)] = \
        plane[max(-dy, 0):hh + min(-dy, 0), max(-dx, 0):ww + min(-dx, 0)]


def warp_state(plane: NDArray[np.float32], h_scaled: Mat3, out: NDArray[np.float32]) -> None:
    """Warp a state plane from previous to current coordinates; uncovered pixels become 0.

    A pure translation is rounded to whole pixels and copied: interpolating would blur the
    delay state a little more every frame, and a blurred ``G_d`` no longer cancels a sharp
    ``G`` in Eq. (10) (the residual sub-pixel motion, <= 0.5 px, is the lesser error).
    """
    hh, ww = plane.shape
    if np.allclose(h_scaled[:2, :2], np.eye(2), atol=1e-9) and np.allclose(
            h_scaled[2], [0.0, 0.0, 1.0]):
        shift_integer(plane, int(round(h_scaled[0, 2])), int(round(h_scaled[1, 2])), out)
    elif np.allclose(h_scaled[2], [0.0, 0.0, 1.0]):
        cv2.warpAffine(plane, h_scaled[:2], (ww, hh), dst=out, flags=cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    else:
        cv2.warpPerspective(plane, h_scaled, (ww, hh), dst=out, flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0)
