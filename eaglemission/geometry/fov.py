"""Where the narrow (long-focus) camera looks inside the wide (short-focus) image (paper
Fig. 4(c)), and the predicate the mission uses to switch cameras.

Calibrated mapping. Both cameras are rigidly mounted on the body (their mounts and lever arms in
the camera configs). For the horizontal plane ``height_above_ground_m`` below the vehicle's
reference point (the ground, or the target's top), a narrow-camera ray meets the plane at a
point that the wide camera sees: the plane-induced homography, in normalised coordinates

    H_norm = R_wn + t_wn n_n^T / d_n        (x_w ~ H_norm x_n, plane n_n . X_n = d_n)

with ``(R_wn, t_wn)`` the narrow -> wide optical transform, ``n_n`` the plane normal in the
narrow frame and ``d_n`` the narrow camera's distance to the plane. Far away ``d_n -> inf`` and
it tends to the infinite homography ``R_wn``; close to the target the lens baseline (the lever
arms) shifts the view by ``|t_wn| / d_n`` radians. Pixels go through each model's
(un)distortion, so the polygon is exact for distorted lenses too.

Refinement. The paper aligns the two images with SURF (not in OpenCV's pip wheels): here SIFT
(or ORB) features of the narrow image, pre-warped into the wide image's geometry by the
calibrated homography, are matched to the wide image around the predicted footprint; a RANSAC
homography corrects the calibrated one when the scene has texture (enough inliers, a bounded
correction), else the calibrated one is kept (:func:`refine_homography`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from eaglemission.geometry import CameraModel, quat_to_R

log = logging.getLogger(__name__)

LEVEL_Q = (1.0, 0.0, 0.0, 0.0)


# ---------------------------------------------------------------------------------------------
# Calibrated geometry
# ---------------------------------------------------------------------------------------------
def relative_pose(wide: CameraModel, narrow: CameraModel) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(R_wn, t_wn)`` with ``X_w = R_wn X_n + t_wn`` (optical frames, metres)."""
    R_bw = wide.mount.R_body_optical
    R_bn = narrow.mount.R_body_optical
    c_w = np.asarray(wide.mount.lever_arm_m, dtype=np.float64)
    c_n = np.asarray(narrow.mount.lever_arm_m, dtype=np.float64)
    return R_bw.T @ R_bn, R_bw.T @ (c_n - c_w)


def plane_homography_normalized(
    wide: CameraModel, narrow: CameraModel, height_above_ground_m: float,
    attitude_q: Sequence[float] | None = None,
) -> NDArray[np.float64]:
    """``H_norm`` (3x3): narrow normalised coordinates -> wide normalised coordinates for the
    horizontal plane ``height_above_ground_m`` below the vehicle's reference point.

    ``attitude_q`` (body FRD -> NED; level if None) orients the plane in the camera frames.
    ``height_above_ground_m = inf`` gives the infinite homography."""
    R_wn, t_wn = relative_pose(wide, narrow)
    if math.isinf(height_above_ground_m):
        return R_wn.copy()
    R_nb = quat_to_R(attitude_q if attitude_q is not None else LEVEL_Q)
    R_no = R_nb @ narrow.mount.R_body_optical  # narrow optical -> NED
    c_n_down = float((R_nb @ np.asarray(narrow.mount.lever_arm_m, dtype=np.float64))[2])
    d_n = height_above_ground_m - c_n_down  # narrow centre's height above the plane
    if not d_n > 0:
        raise ValueError(
            f"height_above_ground_m: the narrow camera must be above the plane, got {d_n:.3f} m")
    n_n = R_no.T @ np.array([0.0, 0.0, 1.0])  # plane normal (down) in the narrow frame
    # Plane: n_n . X_n = d_n.
    return R_wn + np.outer(t_wn, n_n) / d_n


def pixel_homography(wide: CameraModel, narrow: CameraModel, H_norm: NDArray[np.float64]) -> NDArray[np.float64]:
    """Narrow pixels -> wide pixels for pinhole (undistorted) images: ``K_w H_norm K_n^-1``."""
    H = np.asarray(wide.K @ H_norm @ np.linalg.inv(narrow.K), dtype=np.float64)
    out: NDArray[np.float64] = H / H[2, 2]
    return out


def map_points(H_norm: NDArray[np.float64], src: CameraModel, dst: CameraModel,
               pixels: ArrayLike) -> NDArray[np.float64]:
    """Map (n, 2) pixels of ``src`` through ``H_norm`` (src normalised -> dst normalised) into
    ``dst`` pixels, with both lenses' distortion. NaN where the mapped point is behind ``dst``."""
    nrm = src.normalize(np.asarray(pixels, dtype=np.float64).reshape(-1, 2))
    x = np.column_stack((nrm, np.ones(len(nrm)))) @ H_norm.T
    return dst.project(x)


def image_border(model: CameraModel, points_per_edge: int = 8) -> NDArray[np.float64]:
    """(4 * points_per_edge, 2) pixels around the image border, clockwise from top-left."""
    W, H = model.width_px - 0.5, model.height_px - 0.5
    s = np.linspace(0.0, 1.0, points_per_edge, endpoint=False)
    top = np.column_stack((-0.5 + s * (W + 0.5), np.full_like(s, -0.5)))
    right = np.column_stack((np.full_like(s, W), -0.5 + s * (H + 0.5)))
    bottom = np.column_stack((W - s * (W + 0.5), np.full_like(s, H)))
    left = np.column_stack((np.full_like(s, -0.5), H - s * (H + 0.5)))
    return np.vstack((top, right, bottom, left))


def narrow_fov_in_wide(
    wide_model: CameraModel, narrow_model: CameraModel, height_above_ground_m: float, *,
    attitude_q: Sequence[float] | None = None, H_norm: NDArray[np.float64] | None = None,
    points_per_edge: int = 8,
) -> NDArray[np.float64]:
    """Outline (clockwise, (4 * points_per_edge, 2) wide pixels) of the narrow camera's image
    in the wide image, from the calibrated plane-induced mapping (or a given ``H_norm``, e.g. a
    refined one from :func:`refine_homography` via :func:`normalized_from_pixel_homography`).

    Only the 4 corners are needed for undistorted lenses; the extra border points follow a
    distorted edge."""
    if H_norm is None:
        H_norm = plane_homography_normalized(wide_model, narrow_model, height_above_ground_m,
                                             attitude_q)
    return map_points(H_norm, narrow_model, wide_model, image_border(narrow_model, points_per_edge))


def normalized_from_pixel_homography(wide: CameraModel, narrow: CameraModel,
                                     H_px: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of :func:`pixel_homography`."""
    return np.linalg.inv(wide.K) @ H_px @ narrow.K


# ---------------------------------------------------------------------------------------------
# The predicate
# ---------------------------------------------------------------------------------------------
def target_in_narrow_view(
    wide_model: CameraModel, narrow_model: CameraModel, corners_wide_px: ArrayLike, *,
    height_above_ground_m: float, attitude_q: Sequence[float] | None = None,
    H_norm: NDArray[np.float64] | None = None, margin_px: float = 20.0,
    require: Literal["all", "centre"] = "all",
) -> bool:
    """Is the target detected in the wide image inside the narrow camera's view?

    The detection's corners (or their centre, ``require="centre"``) are mapped into the narrow
    image through the plane ``height_above_ground_m`` below the vehicle (the target's top: pass
    the vehicle's height above it) and must land inside the narrow image with ``margin_px``
    (narrow pixels) to spare. ``attitude_q`` is the vehicle attitude at the wide frame's
    exposure time (level if None: pass it, a 5 deg tilt moves the narrow view by ~90 narrow
    pixels). Returns False for non-finite corners or a plane not below the narrow camera.

    Raises
    ------
    ValueError
        ``height_above_ground_m`` not > 0 (a sign error in the caller: the height is
        ``target_down_m - vehicle_down_m``).
    """
    if not (height_above_ground_m > 0):  # also catches NaN
        raise ValueError(
            f"height_above_ground_m: must be > 0 (the vehicle's height above the target's top, "
            f"target_down_m - vehicle_down_m), got {height_above_ground_m}")
    c = np.asarray(corners_wide_px, dtype=np.float64).reshape(-1, 2)
    if c.size == 0 or not np.isfinite(c).all():
        return False
    if require == "centre":
        c = c.mean(axis=0, keepdims=True)
    try:
        if H_norm is None:
            H_norm = plane_homography_normalized(wide_model, narrow_model, height_above_ground_m,
                                                 attitude_q)
        H_inv: NDArray[np.float64] = np.linalg.inv(H_norm).astype(np.float64)
    except (ValueError, np.linalg.LinAlgError) as exc:
        log.debug("target_in_narrow_view: %s", exc)
        return False
    px = map_points(H_inv, wide_model, narrow_model, c)
    return bool(narrow_model.in_image(px, margin_px).all())


# ---------------------------------------------------------------------------------------------
# Feature-based refinement
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class HomographyRefinement:
    """Result of :func:`refine_homography`: the homography to use (narrow px -> wide px), whether
    it is the feature-refined one, and why not if it is the calibrated one."""

    H_px: NDArray[np.float64]
    refined: bool
    inliers: int
    correction_px: float
    reason: str = ""


def _gray(img: NDArray[np.uint8]) -> NDArray[np.uint8]:
    out = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
    return np.asarray(out, dtype=np.uint8)


def refine_homography(
    wide_image: NDArray[np.uint8], narrow_image: NDArray[np.uint8], H_px_calibrated: NDArray[np.float64],
    *, method: Literal["sift", "orb"] = "sift", min_inliers: int = 20,
    max_correction_px: float = 60.0, ransac_px: float = 3.0, margin_px: int = 40,
    max_features: int = 1500,
) -> HomographyRefinement:
    """Correct the calibrated narrow -> wide homography by feature matching.

    The narrow image is warped into the wide image's geometry with the calibrated homography
    (so both have the same scale: the 12 mm / 2.8 mm images differ by 4.3x), features are
    matched between that warp and the wide image inside the predicted footprint (+ margin),
    and a RANSAC homography between them gives the correction. The calibrated homography is
    kept when there are fewer than ``min_inliers`` inliers (no texture, e.g. snow or sky) or
    the correction moves a footprint corner by more than ``max_correction_px`` wide pixels.
    """
    Hc = np.asarray(H_px_calibrated, dtype=np.float64)
    wg, ng = _gray(wide_image), _gray(narrow_image)
    hn, wn = ng.shape
    hw, ww = wg.shape
    corners_n = np.array([[0, 0], [wn - 1, 0], [wn - 1, hn - 1], [0, hn - 1]], dtype=np.float64)
    fp = cv2.perspectiveTransform(corners_n.reshape(-1, 1, 2), Hc).reshape(-1, 2)
    if not np.isfinite(fp).all():
        return HomographyRefinement(Hc, False, 0, 0.0, "calibrated footprint not finite")
    x0 = int(max(0, math.floor(fp[:, 0].min()) - margin_px))
    y0 = int(max(0, math.floor(fp[:, 1].min()) - margin_px))
    x1 = int(min(ww, math.ceil(fp[:, 0].max()) + margin_px))
    y1 = int(min(hw, math.ceil(fp[:, 1].max()) + margin_px))
    if x1 - x0 < 16 or y1 - y0 < 16:
        return HomographyRefinement(Hc, False, 0, 0.0, "footprint outside the wide image")
    T = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1]], dtype=np.float64)
    warped = cv2.warpPerspective(ng, T @ Hc, (x1 - x0, y1 - y0), flags=cv2.INTER_AREA)
    valid = cv2.warpPerspective(np.full_like(ng, 255), T @ Hc, (x1 - x0, y1 - y0),
                                flags=cv2.INTER_NEAREST)
    valid = cv2.erode(valid, np.ones((5, 5), np.uint8))
    roi = np.ascontiguousarray(wg[y0:y1, x0:x1])
    if method == "sift":
        det = getattr(cv2, "SIFT_create")(nfeatures=max_features)  # noqa: B009 - cv2's stubs omit the feature factories
        norm = cv2.NORM_L2
    else:
        det = getattr(cv2, "ORB_create")(nfeatures=max_features)  # noqa: B009 - cv2's stubs omit the feature factories
        norm = cv2.NORM_HAMMING
    kp_w, des_w = det.detectAndCompute(warped, valid)
    kp_r, des_r = det.detectAndCompute(roi, None)
    if des_w is None or des_r is None or len(kp_w) < min_inliers or len(kp_r) < min_inliers:
        return HomographyRefinement(Hc, False, 0, 0.0, "too few features (no texture)")
    matcher = cv2.BFMatcher(norm)
    pairs = matcher.knnMatch(des_w, des_r, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.75 * p[1].distance]
    if len(good) < min_inliers:
        return HomographyRefinement(Hc, False, len(good), 0.0, "too few distinctive matches")
    src = np.asarray([kp_w[m.queryIdx].pt for m in good], dtype=np.float32).reshape(-1, 1, 2)
    dst = np.asarray([kp_r[m.trainIdx].pt for m in good], dtype=np.float32).reshape(-1, 1, 2)
    Hr, mask = cv2.findHomography(src, dst, cv2.RANSAC, ransac_px)
    inliers = int(mask.sum()) if mask is not None else 0
    if Hr is None or inliers < min_inliers:
        return HomographyRefinement(Hc, False, inliers, 0.0, "RANSAC found no consistent homography")
    # Warped (ROI) coordinates -> wide ROI coordinates; back to full-image coordinates.
    H = np.linalg.inv(T) @ Hr @ T @ Hc
    H /= H[2, 2]
    fp_new = cv2.perspectiveTransform(corners_n.reshape(-1, 1, 2), H).reshape(-1, 2)
    corr = float(np.linalg.norm(fp_new - fp, axis=1).max())
    if not np.isfinite(corr) or corr > max_correction_px:
        return HomographyRefinement(Hc, False, inliers, corr,
                                    f"correction {corr:.0f} px > max_correction_px={max_correction_px:g}")
    return HomographyRefinement(H, True, inliers, corr)
