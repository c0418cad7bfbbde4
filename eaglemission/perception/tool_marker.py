"""Seeing the tool: find its ArUco marker (:class:`~eaglemission.geometry.tool_marker.
ToolMarker`) in a frame and measure where the tool is in the camera's frame.

OpenCV's ``aruco`` detector on a window around where the marker should be, then
``solvePnP(SOLVEPNP_IPPE_SQUARE)`` on its four corners for the marker's centre in the optical
frame (its translation is well conditioned where its rotation, at a few tens of pixels, is
not: only the centre is used).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
import numpy.typing as npt

from eaglemission.geometry import CameraModel
from eaglemission.geometry.tool_marker import ToolMarker, marker_corners_body
from eaglemission.types import XYZ

Box = tuple[int, int, int, int]


@functools.lru_cache(maxsize=8)
def _detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), params)


def marker_image(marker: ToolMarker, side_px: int) -> npt.NDArray[np.uint8]:
    """The marker's black square as an image of ``side_px`` (what is printed on the plate)."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, marker.dictionary))
    out = np.asarray(cv2.aruco.generateImageMarker(d, marker.marker_id, side_px), np.uint8)
    return out


def body_points_cam(model: CameraModel, points_body_m: npt.ArrayLike
                    ) -> npt.NDArray[np.float64]:
    """(n, 3) points fixed to the body (FRD) in the camera's optical frame, through its
    believed mount (the vehicle's pose does not enter: both are on the body)."""
    mount = model.mount
    pts = np.asarray(points_body_m, dtype=np.float64).reshape(-1, 3)
    cam: npt.NDArray[np.float64] = (pts - np.asarray(mount.lever_arm_m)) @ mount.R_body_optical
    return cam


def tool_footprint_px(model: CameraModel, tool_body_m: XYZ, radius_m: float,
                      marker: ToolMarker | None = None, min_depth_m: float = 0.02
                      ) -> npt.NDArray[np.float32] | None:
    """The convex image polygon (float32 (n, 2)) covering the tool as the camera sees it: a
    cube of half-side ``radius_m`` around the tool point and, with a marker, its plate (or the
    marker's square without one); None when part of it is not in front of the camera or none
    of it is inside the image."""
    c = np.asarray(tool_body_m, dtype=np.float64)
    r = float(radius_m)
    pts = [c + (sx * r, sy * r, sz * r) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    if marker is not None:
        pts.extend(marker_corners_body(marker, tool_body_m, marker.plate_m or None))
    cam = body_points_cam(model, pts)
    if not (cam[:, 2] > min_depth_m).all():
        return None
    px = model.project(cam)
    if not np.isfinite(px).all():
        return None
    lo, hi = px.min(axis=0), px.max(axis=0)
    if hi[0] < 0 or hi[1] < 0 or lo[0] >= model.width_px or lo[1] >= model.height_px:
        return None
    hull = cv2.convexHull(px.astype(np.float32))
    return np.asarray(hull, dtype=np.float32).reshape(-1, 2)


def predicted_box_px(marker: ToolMarker, model: CameraModel, tool_body_m: XYZ,
                     grow: float = 1.0) -> Box | None:
    """The pixel window where the marker should be with the tool at ``tool_body_m`` (the
    camera's believed mount), grown by ``grow`` times its size on each side; None when it is
    not wholly in front of the camera and inside the image."""
    cam = body_points_cam(model, marker_corners_body(marker, tool_body_m))
    if not (cam[:, 2] > 0).all():
        return None
    px = model.project(cam)
    if not np.isfinite(px).all():
        return None
    (u0, v0), (u1, v1) = px.min(axis=0), px.max(axis=0)
    gu, gv = grow * (u1 - u0), grow * (v1 - v0)
    if u0 < 0 or v0 < 0 or u1 >= model.width_px or v1 >= model.height_px:
        return None
    return (max(0, int(u0 - gu)), max(0, int(v0 - gv)),
            min(model.width_px, int(u1 + gu) + 1), min(model.height_px, int(v1 + gv) + 1))


def find_marker(image: npt.NDArray[np.uint8], marker: ToolMarker, box_px: Box | None = None
                ) -> npt.NDArray[np.float64] | None:
    """(4, 2) corners of the marker (its id, in ArUco's order, full-image pixels) found in
    ``image`` (inside ``box_px``: u0, v0, u1, v1); None when it is not seen exactly once."""
    u0, v0, u1, v1 = box_px if box_px is not None else (0, 0, image.shape[1], image.shape[0])
    crop = image[v0:v1, u0:u1]
    if crop.size == 0:
        return None
    grey = cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY) if crop.ndim == 3 else crop
    corners, ids, _ = _detector(marker.dictionary).detectMarkers(grey)
    if ids is None:
        return None
    mine = [c for c, i in zip(corners, ids.ravel()) if int(i) == marker.marker_id]
    if len(mine) != 1:
        return None
    out: npt.NDArray[np.float64] = mine[0].reshape(4, 2).astype(np.float64) + (u0, v0)
    return out


def marker_centre_cam(corners_px: npt.ArrayLike, marker: ToolMarker, model: CameraModel
                      ) -> XYZ | None:
    """The marker's centre in the optical frame (m) from its four corners (ArUco's order);
    None when the pose cannot be solved."""
    s = marker.side_m / 2
    obj = np.array([[-s, s, 0.0], [s, s, 0.0], [s, -s, 0.0], [-s, -s, 0.0]])
    img = np.asarray(corners_px, dtype=np.float64).reshape(4, 1, 2)
    ok, _rvec, tvec = cv2.solvePnP(obj, img, np.asarray(model.K, dtype=np.float64),
                                   model.dist_array, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    t = np.asarray(tvec, dtype=np.float64).ravel()
    if not ok or not np.isfinite(t).all() or t[2] <= 0:
        return None
    return (float(t[0]), float(t[1]), float(t[2]))


def tool_body_from_marker(centre_cam_m: XYZ, marker: ToolMarker, model: CameraModel) -> XYZ:
    """The tool point in body FRD, through the camera's believed mount, from the marker's
    centre in the optical frame."""
    mount = model.mount
    b = (np.asarray(mount.lever_arm_m) + mount.R_body_optical @ np.asarray(centre_cam_m)
         - np.asarray(marker.centre_from_tool_m))
    return (float(b[0]), float(b[1]), float(b[2]))
