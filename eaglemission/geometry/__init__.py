"""Geometry: rotations, the camera model and frame transforms (:mod:`.frames`), calibration
files (:mod:`.calibration`), the narrow camera's view inside the wide image (:mod:`.fov`) and
the geofence (:mod:`.geofence`). Conventions: docs/conventions.md."""

from eaglemission.geometry.frames import (
    R_FRD_FROM_OPTICAL,
    CameraModel,
    CameraMount,
    Pose,
    R_to_euler,
    R_to_quat,
    angle_between_rotations_deg,
    body_pose_ned,
    camera_pose_ned,
    down_axis_cos_tilt,
    euler_to_quat,
    euler_to_R,
    geodetic_to_ned,
    intersect_ray_with_horizontal_plane,
    intrinsics_from_lens,
    ned_to_geodetic,
    order_corners,
    quat_slerp,
    quat_to_R,
    ray_plane_points,
    rot_z,
    rotation_from_vector,
    rotation_vector,
    wrap_deg,
)

__all__ = [
    "R_FRD_FROM_OPTICAL", "CameraModel", "CameraMount", "Pose", "R_to_euler", "R_to_quat",
    "angle_between_rotations_deg", "body_pose_ned", "camera_pose_ned", "down_axis_cos_tilt",
    "euler_to_quat", "euler_to_R", "geodetic_to_ned", "intersect_ray_with_horizontal_plane",
    "intrinsics_from_lens", "ned_to_geodetic", "order_corners", "quat_slerp", "quat_to_R",
    "ray_plane_points", "rot_z", "rotation_from_vector", "rotation_vector", "wrap_deg",
]
