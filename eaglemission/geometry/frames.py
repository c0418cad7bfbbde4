"""Rotations, the camera model, frame transforms and geodetic conversion (docs/conventions.md).

Frames: local NED (origin at home), body FRD, camera optical (x right, y down, z forward).
A camera's mount is given as the Euler angles (ZYX: yaw, pitch, roll) of a "camera FRD" frame
(x along the optical axis, y right, z down) relative to body FRD, plus the lever arm of the
camera centre in body FRD. ``pitch_deg = -30`` tilts the optical axis 30 deg below the
horizontal, as in the paper.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from eaglemission.types import XYZ, GeoPoint, Mat3, Points2, Points3, Quat, Shutter, Vec3

# Optical (x right, y down, z forward) -> camera FRD (x forward, y right, z down).
R_FRD_FROM_OPTICAL: Mat3 = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

# Termination of the iterative point undistortion (CameraModel.normalize).
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


# ---------------------------------------------------------------------------------------------
# Rotations
# ---------------------------------------------------------------------------------------------
def rot_x(angle_rad: float) -> Mat3:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> Mat3:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> Mat3:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def euler_to_R(roll_deg: float, pitch_deg: float, yaw_deg: float) -> Mat3:
    """ZYX (yaw, then pitch, then roll) Euler angles to the rotation child -> parent."""
    return rot_z(math.radians(yaw_deg)) @ rot_y(math.radians(pitch_deg)) @ rot_x(
        math.radians(roll_deg)
    )


def R_to_euler(R: Mat3) -> tuple[float, float, float]:
    """Inverse of :func:`euler_to_R`: (roll_deg, pitch_deg, yaw_deg)."""
    pitch = math.asin(max(-1.0, min(1.0, -float(R[2, 0]))))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


def quat_to_R(q: Sequence[float]) -> Mat3:
    """Unit quaternion ``(w, x, y, z)`` to rotation matrix (Hamilton convention)."""
    w, x, y, z = (float(v) for v in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not n > 0.0 or not math.isfinite(n):
        raise ValueError(f"quaternion: must be finite and non-zero, got {tuple(q)}")
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def down_axis_cos_tilt(q: Sequence[float]) -> float:
    """Cosine of the angle between the body's down axis and the vertical for a unit attitude
    quaternion ``(w, x, y, z)`` (body FRD -> NED): the NED down component of body z,
    ``1 - 2 (x^2 + y^2)``. A downward range ``d`` spans ``d * cos_tilt`` vertically."""
    return 1.0 - 2.0 * (float(q[1]) ** 2 + float(q[2]) ** 2)


def R_to_quat(R: Mat3) -> Quat:
    """Rotation matrix to unit quaternion ``(w, x, y, z)`` with ``w >= 0``."""
    m = np.asarray(R, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    q = np.array([w, x, y, z], dtype=np.float64)
    q /= np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def euler_to_quat(roll_deg: float, pitch_deg: float, yaw_deg: float) -> Quat:
    return R_to_quat(euler_to_R(roll_deg, pitch_deg, yaw_deg))


def quat_slerp(q0: Sequence[float], q1: Sequence[float], alpha: float) -> Quat:
    """Spherical interpolation between unit quaternions, shortest arc."""
    a = np.asarray(q0, dtype=np.float64)
    b = np.asarray(q1, dtype=np.float64)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    dot = float(a @ b)
    if dot < 0.0:
        b, dot = -b, -dot
    if dot > 0.9995:
        q = a + alpha * (b - a)
    else:
        theta = math.acos(dot)
        q = (math.sin((1 - alpha) * theta) * a + math.sin(alpha * theta) * b) / math.sin(theta)
    q /= np.linalg.norm(q)
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def rotation_vector(R: Mat3) -> NDArray[np.float64]:
    """The rotation vector (axis x angle, rad) of a rotation matrix (angle < pi)."""
    w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = float(np.linalg.norm(w))
    angle = math.atan2(s, 0.5 * (float(np.trace(R)) - 1.0))
    return np.asarray(w * (angle / s) if s > 1e-12 else w, dtype=np.float64)


def rotation_from_vector(rotvec: Sequence[float] | NDArray[np.float64]) -> Mat3:
    """The rotation matrix of a rotation vector (axis x angle, rad): Rodrigues' formula."""
    r = np.asarray(rotvec, dtype=np.float64)
    angle = float(np.linalg.norm(r))
    if angle < 1e-12:
        return np.eye(3)
    k = r / angle
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.asarray(np.eye(3) + math.sin(angle) * Kx + (1.0 - math.cos(angle)) * Kx @ Kx,
                      dtype=np.float64)


def wrap_deg(angle_deg: float) -> float:
    """Wrap an angle to [-180, 180)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def angle_between_rotations_deg(Ra: Mat3, Rb: Mat3) -> float:
    """Geodesic angle of ``Ra^T Rb`` in degrees."""
    c = (float(np.trace(np.asarray(Ra).T @ np.asarray(Rb))) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


# ---------------------------------------------------------------------------------------------
# Geodetic <-> local NED (local tangent plane at home; errors < 1 cm within 1 km)
# ---------------------------------------------------------------------------------------------
def _radii_m(latitude_deg: float) -> tuple[float, float]:
    s = math.sin(math.radians(latitude_deg))
    d = 1.0 - WGS84_E2 * s * s
    r_meridian = WGS84_A_M * (1.0 - WGS84_E2) / d**1.5
    r_normal = WGS84_A_M / math.sqrt(d)
    return r_meridian, r_normal


def ned_to_geodetic(home: GeoPoint, north_m: float, east_m: float, down_m: float) -> GeoPoint:
    rm, rn = _radii_m(home.latitude_deg)
    lat = home.latitude_deg + math.degrees(north_m / rm)
    lon = home.longitude_deg + math.degrees(east_m / (rn * math.cos(math.radians(home.latitude_deg))))
    return GeoPoint(lat, lon, home.altitude_amsl_m - down_m)


def geodetic_to_ned(home: GeoPoint, point: GeoPoint) -> XYZ:
    rm, rn = _radii_m(home.latitude_deg)
    north = math.radians(point.latitude_deg - home.latitude_deg) * rm
    east = math.radians(point.longitude_deg - home.longitude_deg) * rn * math.cos(
        math.radians(home.latitude_deg)
    )
    return (north, east, home.altitude_amsl_m - point.altitude_amsl_m)


# ---------------------------------------------------------------------------------------------
# Camera model
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraMount:
    """Mount of a camera on the body: Euler angles of camera FRD relative to body FRD, and the
    lever arm (camera centre in body FRD, metres)."""

    roll_deg: float = 0.0
    pitch_deg: float = -30.0
    yaw_deg: float = 0.0
    lever_arm_m: XYZ = (0.0, 0.0, 0.0)

    @property
    def R_body_optical(self) -> Mat3:
        """Rotation optical -> body FRD."""
        return euler_to_R(self.roll_deg, self.pitch_deg, self.yaw_deg) @ R_FRD_FROM_OPTICAL


def intrinsics_from_lens(
    focal_length_mm: float, pixel_size_um: float, width_px: int, height_px: int
) -> Mat3:
    """Pinhole K from focal length, pixel pitch and resolution, principal point at the centre
    (pixel centres at integer coordinates, so the centre is ((W-1)/2, (H-1)/2))."""
    if not (focal_length_mm > 0 and pixel_size_um > 0 and width_px > 0 and height_px > 0):
        raise ValueError(
            "intrinsics_from_lens: focal_length_mm, pixel_size_um, width_px, height_px must be > 0"
        )
    f_px = focal_length_mm * 1e3 / pixel_size_um
    return np.array(
        [[f_px, 0.0, (width_px - 1) / 2.0], [0.0, f_px, (height_px - 1) / 2.0], [0.0, 0.0, 1.0]]
    )


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics, distortion, shutter and mount of one camera.

    ``K`` is the 3x3 pinhole matrix in pixels; ``distortion`` follows OpenCV's order
    ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``.
    """

    camera_id: str
    width_px: int
    height_px: int
    K: Mat3
    distortion: tuple[float, ...] = ()
    pixel_size_um: float = 3.75
    focal_length_mm: float = float("nan")
    shutter: Shutter = "global"
    exposure_s: float = 0.005
    mount: CameraMount = field(default_factory=CameraMount)

    @classmethod
    def from_lens(
        cls,
        camera_id: str,
        *,
        focal_length_mm: float,
        pixel_size_um: float = 3.75,
        resolution_px: tuple[int, int] = (1280, 960),
        mount: CameraMount | None = None,
        distortion: tuple[float, ...] = (),
        shutter: Shutter = "global",
        exposure_s: float = 0.005,
    ) -> CameraModel:
        w, h = resolution_px
        K = intrinsics_from_lens(focal_length_mm, pixel_size_um, w, h)
        return cls(camera_id, w, h, K, distortion=tuple(distortion), pixel_size_um=pixel_size_um,
                   focal_length_mm=focal_length_mm, shutter=shutter, exposure_s=exposure_s,
                   mount=mount or CameraMount())

    def with_(self, *, K: Mat3 | None = None, mount: CameraMount | None = None,
              distortion: tuple[float, ...] | None = None,
              focal_length_mm: float | None = None) -> CameraModel:
        """A copy with some of the intrinsics, mount or distortion replaced."""
        return replace(self, K=self.K if K is None else K,
                       mount=self.mount if mount is None else mount,
                       distortion=self.distortion if distortion is None else distortion,
                       focal_length_mm=(self.focal_length_mm if focal_length_mm is None
                                        else focal_length_mm))

    # -- intrinsics -----------------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view (pinhole, ignoring distortion)."""
        return (
            math.degrees(2 * math.atan(self.width_px / (2 * self.fx))),
            math.degrees(2 * math.atan(self.height_px / (2 * self.fy))),
        )

    @property
    def dist_array(self) -> NDArray[np.float64]:
        return np.asarray(self.distortion, dtype=np.float64) if self.distortion else np.zeros(5)

    # -- projection -----------------------------------------------------------------------------
    def project(self, points_cam: ArrayLike) -> Points2:
        """Project (n, 3) optical-frame points to (n, 2) pixels (with distortion).
        Points with z <= 0 come back as NaN."""
        p = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        out = np.full((p.shape[0], 2), np.nan)
        ok = p[:, 2] > 1e-9
        if ok.any():
            if self.distortion and any(self.distortion):
                img, _ = cv2.projectPoints(p[ok], np.zeros(3), np.zeros(3), self.K, self.dist_array)
                out[ok] = img.reshape(-1, 2)
            else:
                q = p[ok]
                out[ok, 0] = self.fx * q[:, 0] / q[:, 2] + self.cx
                out[ok, 1] = self.fy * q[:, 1] / q[:, 2] + self.cy
        return out

    def normalize(self, pixels: ArrayLike) -> Points2:
        """Undistort (n, 2) pixels to normalised image coordinates ``(x/z, y/z)``."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if self.distortion and any(self.distortion):
            # OpenCV's default (5 fixed-point iterations) leaves ~1 px at the corners of a
            # 2.8 mm lens with k1 = -0.3; iterate to convergence instead.
            und = cv2.undistortPoints(px.reshape(-1, 1, 2), self.K, self.dist_array, None, None,
                                      None, UNDISTORT_CRITERIA)
            return np.asarray(und, dtype=np.float64).reshape(-1, 2)
        return np.column_stack(((px[:, 0] - self.cx) / self.fx, (px[:, 1] - self.cy) / self.fy)).astype(np.float64)

    def rays_optical(self, pixels: ArrayLike) -> Points3:
        """Unit rays in the optical frame through (n, 2) pixels."""
        n = self.normalize(pixels)
        r = np.column_stack((n, np.ones(len(n))))
        out: Points3 = r / np.linalg.norm(r, axis=1, keepdims=True)
        return out

    def in_image(self, pixels: ArrayLike, margin_px: float = 0.0) -> NDArray[np.bool_]:
        p = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        return (
            np.isfinite(p).all(axis=1)
            & (p[:, 0] >= -0.5 + margin_px)
            & (p[:, 0] <= self.width_px - 0.5 - margin_px)
            & (p[:, 1] >= -0.5 + margin_px)
            & (p[:, 1] <= self.height_px - 0.5 - margin_px)
        )


# ---------------------------------------------------------------------------------------------
# Poses: camera <-> body <-> NED
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Pose:
    """Rigid transform child -> parent: ``x_parent = R @ x_child + t``."""

    R: Mat3
    t: Vec3

    def apply(self, points: ArrayLike) -> NDArray[np.float64]:
        p = np.asarray(points, dtype=np.float64)
        return p @ self.R.T + self.t

    def inverse(self) -> Pose:
        return Pose(self.R.T, -self.R.T @ self.t)

    def __matmul__(self, other: Pose) -> Pose:
        return Pose(self.R @ other.R, self.R @ other.t + self.t)


def body_pose_ned(position_ned_m: Sequence[float], attitude_q: Sequence[float]) -> Pose:
    """Body FRD -> NED pose from a vehicle position and attitude quaternion."""
    return Pose(quat_to_R(attitude_q), np.asarray(position_ned_m, dtype=np.float64))


def camera_pose_ned(
    model: CameraModel, position_ned_m: Sequence[float], attitude_q: Sequence[float]
) -> Pose:
    """Optical -> NED pose of a camera on a vehicle at the given position and attitude."""
    mount = Pose(model.mount.R_body_optical, np.asarray(model.mount.lever_arm_m, dtype=np.float64))
    return body_pose_ned(position_ned_m, attitude_q) @ mount


def ray_plane_points(origin_ned_m: Sequence[float] | NDArray[np.float64], directions_ned: Any,
                     down_m: float, *,
                     min_down: float = 1e-9) -> NDArray[np.float64]:
    """Where rays from one origin meet the horizontal plane ``down = down_m`` (NED).

    Parameters
    ----------
    origin_ned_m : (3,) the rays' common origin
    directions_ned : (n, 3) ray directions (any length)
    down_m : the plane's down coordinate
    min_down : a ray must point down by more than this (its direction's down component):
        a ray at or above the horizon never meets a plane below

    Returns
    -------
    ndarray of shape (n, 3): the points, NaN rows where a ray does not reach the plane
    (pointing too little down, or the plane is not below the origin).
    """
    o = np.asarray(origin_ned_m, dtype=np.float64)
    d = np.asarray(directions_ned, dtype=np.float64).reshape(-1, 3)
    out = np.full(d.shape, np.nan)
    drop = float(down_m) - float(o[2])
    ok = d[:, 2] > min_down
    if drop <= 0 or not ok.any():
        return out
    out[ok] = o + d[ok] * (drop / d[ok, 2:3])
    return out


def intersect_ray_with_horizontal_plane(
    origin_ned_m: Sequence[float], direction_ned: Sequence[float], down_m: float
) -> Vec3 | None:
    """Point where a ray meets the horizontal plane ``d = down_m``; None if it never does
    (ray at or above the horizon w.r.t. that plane, or the plane is behind)."""
    hit = ray_plane_points(origin_ned_m, [direction_ned], down_m)[0]
    return None if not np.isfinite(hit).all() else hit


# Ties in u + v closer than this (pixels) are broken by v (float noise from boxPoints).
_TIE_PX = 1e-6


def order_corners(corners: Any) -> NDArray[np.float64]:
    """Order 4 corners clockwise on screen starting from the top-left one
    (docs/conventions.md).

    Parameters
    ----------
    corners : array_like of shape (4, 2)
        ``(u, v)`` pixel coordinates (u right, v down) of a convex quadrilateral, any order.

    Returns
    -------
    ndarray of shape (4, 2), float64
        Clockwise on screen, first the corner with the smallest ``u + v`` (ties, within 1e-6
        px: the smaller ``v``).
    """
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    centre = c.mean(axis=0)
    # On screen with v down, increasing atan2(v, u) turns clockwise.
    ang = np.arctan2(c[:, 1] - centre[1], c[:, 0] - centre[0])
    c = c[np.argsort(ang, kind="stable")]
    s = c[:, 0] + c[:, 1]
    candidates = np.flatnonzero(s <= s.min() + _TIE_PX)
    start = int(candidates[np.argmin(c[candidates, 1])])
    return np.roll(c, -start, axis=0)
