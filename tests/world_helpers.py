"""Helpers shared by the estimator tests (plain functions, imported by name: the tests folder
is on sys.path under pytest's default import mode)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from eaglemission.geometry import euler_to_quat, order_corners
from eaglemission.interfaces.estimator import CameraView
from eaglemission.types import Detection, VehicleState


def detection_from_polygon(poly: np.ndarray, camera_id: str = "narrow") -> Detection:
    """What a perfect segmentation of the target gives: the MBR of its silhouette."""
    rect = cv2.minAreaRect(np.asarray(poly, dtype=np.float32))
    corners = order_corners(cv2.boxPoints(rect).astype(np.float64))
    w, h = rect[1]
    return Detection(score=1.0, center_px=(float(rect[0][0]), float(rect[0][1])),
                     corners_px=corners, size_px=(float(max(w, h)), float(min(w, h))),
                     angle_deg=float(rect[2]), area_px=float(w * h), camera_id=camera_id)


def approach_pose(target_ned, range_m: float, depression_deg: float, azimuth_deg: float,
                  *, yaw_offset_deg: float = 0.0, roll_deg: float = 0.0, pitch_deg: float = 0.0):
    """Vehicle position and attitude looking at the target from ``range_m`` (slant, from the
    vehicle reference point) at ``depression_deg`` below the horizon, coming from
    ``azimuth_deg``."""
    dep = math.radians(depression_deg)
    az = math.radians(azimuth_deg)
    hd, vh = range_m * math.cos(dep), range_m * math.sin(dep)
    pos = np.asarray(target_ned, dtype=np.float64) + np.array(
        [-hd * math.cos(az), -hd * math.sin(az), -vh])
    q = euler_to_quat(roll_deg, pitch_deg, azimuth_deg + yaw_offset_deg)
    return pos, q


def view_at(model, pos, q, t_ns: int = 10**9) -> CameraView:
    state = VehicleState(timestamp_ns=t_ns, position_ned_m=tuple(float(v) for v in pos),
                         velocity_ned_mps=(0.0, 0.0, 0.0), attitude_q=q)
    return CameraView(model=model, vehicle=state, timestamp_ns=t_ns)
