"""Core value types shared by every role. Units and frames are in the names.

Conventions (docs/conventions.md): timestamps are host ``CLOCK_MONOTONIC`` nanoseconds, a
frame's timestamp is the middle of its exposure; positions are local NED metres with the origin
at home; attitudes are unit quaternions ``(w, x, y, z)`` rotating body-FRD vectors into NED;
pixels are ``(u, v) = (column, row)``; rectangle corners are ordered clockwise on screen
starting from the top-left corner.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Literal, TypeAlias

import numpy as np
from numpy.typing import NDArray

# Shape-named aliases (cf. spatialmath's SO3Array).
Mat3: TypeAlias = NDArray[np.float64]  # (3, 3)
Vec3: TypeAlias = NDArray[np.float64]  # (3,)
Points2: TypeAlias = NDArray[np.float64]  # (n, 2)
Points3: TypeAlias = NDArray[np.float64]  # (n, 3)
Image: TypeAlias = NDArray[np.uint8]  # (H, W, 3) BGR or (H, W) mono
Saliency: TypeAlias = NDArray[np.float32]  # (H, W) in [0, 1]

XYZ: TypeAlias = tuple[float, float, float]
Quat: TypeAlias = tuple[float, float, float, float]  # (w, x, y, z)


def _readonly(a: NDArray[np.generic]) -> NDArray[np.generic]:
    a.flags.writeable = False
    return a


# ---------------------------------------------------------------------------------------------
# Frames
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Frame:
    """One camera image, owned (never a view of a driver buffer) and read-only.

    Attributes
    ----------
    image : ndarray of shape (H, W, 3) BGR uint8, or (H, W) uint8 for mono cameras
    timestamp_ns : host monotonic time of the middle of the exposure
    camera_id : the rig's name for the camera (``"wide"``, ``"narrow"``)
    seq : frame counter of this camera, strictly increasing (gaps mean dropped frames)
    exposure_s : exposure time, 0 when unknown
    device_timestamp_ns : the camera's own stamp of the frame (its clock, ns; GenICam's
        buffer timestamp), before mapping to the host clock; None when the device has none
    """

    image: Image
    timestamp_ns: int
    camera_id: str
    seq: int
    exposure_s: float = 0.0
    device_timestamp_ns: int | None = None

    def __post_init__(self) -> None:
        img = self.image
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8:
            raise ValueError(
                f"Frame.image: must be a uint8 ndarray, got "
                f"{type(img).__name__} {getattr(img, 'dtype', '')}"
            )
        if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3) or img.size == 0:
            raise ValueError(f"Frame.image: must be (H, W, 3) or (H, W), got shape {img.shape}")
        if img.flags.writeable:
            img.flags.writeable = False

    @property
    def height_px(self) -> int:
        return int(self.image.shape[0])

    @property
    def width_px(self) -> int:
        return int(self.image.shape[1])


# ---------------------------------------------------------------------------------------------
# Detections
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Detection:
    """A candidate target region.

    ``corners_px`` is (4, 2) float64 ``(u, v)``, clockwise on screen from the top-left corner
    (the corner with the smallest ``u + v``); ``size_px`` is (long side, short side).
    ``hull_px``, when the detector kept it, is the convex hull of the region's outline, (N, 2)
    float64 ``(u, v)``: its shape beyond the MBR (the silhouette check, docs/mission.md).
    """

    score: float
    center_px: tuple[float, float]
    corners_px: Points2
    size_px: tuple[float, float]
    angle_deg: float
    area_px: float
    camera_id: str = ""
    hull_px: Points2 | None = None

    def __post_init__(self) -> None:
        c = np.asarray(self.corners_px, dtype=np.float64)
        if c.shape != (4, 2):
            raise ValueError(f"Detection.corners_px: must be (4, 2), got {c.shape}")
        object.__setattr__(self, "corners_px", _readonly(c.copy()))
        if self.hull_px is not None:
            h = np.asarray(self.hull_px, dtype=np.float64).reshape(-1, 2)
            if len(h) < 3:
                raise ValueError(f"Detection.hull_px: needs at least 3 points, got {len(h)}")
            object.__setattr__(self, "hull_px", _readonly(h.copy()))

    @property
    def aspect_ratio(self) -> float:
        long_, short = self.size_px
        return float(long_ / short) if short > 0 else math.inf


@dataclass(frozen=True, slots=True)
class TargetPrior:
    """What a detector may assume about the target's image: projected size and shape."""

    min_area_px: float = 16.0
    max_area_px: float = math.inf
    aspect_ratio: float | None = None  # long/short side of the target's top face
    aspect_tolerance: float = 0.5  # relative


@dataclass(frozen=True, slots=True)
class DetectionResult:
    """What every detector returns: a saliency map in [0, 1] at frame resolution + detections."""

    saliency: Saliency
    detections: tuple[Detection, ...]
    timestamp_ns: int
    camera_id: str
    seq: int
    threshold: float = 120.0 / 255.0

    @property
    def best(self) -> Detection | None:
        return self.detections[0] if self.detections else None


# ---------------------------------------------------------------------------------------------
# Estimation
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class PoseEstimate:
    """Object pose in the camera frame: ``X_c = R @ X_o + t_m``. Truthy."""

    R: Mat3
    t_m: Vec3
    reprojection_error: float = 0.0  # mean, in normalised image units unless stated
    candidates: tuple[tuple[Mat3, Vec3], ...] = ()

    def __bool__(self) -> bool:
        return True


@dataclass(frozen=True, slots=True)
class EstimationFailed:
    """Falsy failure value with the reason (skimage's ``FailedEstimation``)."""

    reason: str

    def __bool__(self) -> bool:
        return False

    def __str__(self) -> str:
        return self.reason


@dataclass(frozen=True, slots=True)
class TargetEstimate:
    """Where a target is, from one frame. Truthy.

    ``position_cam_m`` is in the camera optical frame; ``position_ned_m`` in local NED (both the
    target's reference point: the centre of its top face). ``full_3d`` is False for estimators
    that only give the offset parallel to the image plane (paper Eq. 16).
    """

    position_ned_m: XYZ
    position_cam_m: XYZ
    timestamp_ns: int
    camera_id: str
    source: str
    full_3d: bool = True
    yaw_deg: float | None = None
    std_m: float = 0.5
    pose: PoseEstimate | None = None
    fit_cost: float | None = None
    """The plane fit's mismatch when the position is its fit (:class:`PlaneFit`'s ``cost``)."""

    def __bool__(self) -> bool:
        return True


@dataclass(frozen=True, slots=True)
class PlaneFit:
    """Where a detection's target is when its top face lies on a known horizontal plane
    (:class:`~eaglemission.interfaces.fitter.PlaneFitter`): the top-face centre in NED, the
    region model that explained the detection (``"top"`` face or whole ``"box"`` silhouette),
    the target heading tried (deg, 0-180), the MBR side-length mismatch (sum of |log ratio|)
    and the detection-to-model size ratio (> 1: the detection is larger).
    ``silhouette_iou``: for a detection with its outline's hull, seen whole, how well the
    target's own shape explains that outline (the best IoU over headings and region models,
    :func:`~eaglemission.estimators.top_plane.silhouette_iou`) and the heading (deg, 0-180) that
    fits the outline best (``silhouette_yaw_deg``); None when not measured."""

    position_ned_m: XYZ
    region: str
    yaw_deg: float
    cost: float
    size_ratio: float
    silhouette_iou: float | None = None
    silhouette_yaw_deg: float | None = None


# ---------------------------------------------------------------------------------------------
# Vehicle
# ---------------------------------------------------------------------------------------------
class FlightMode(enum.StrEnum):
    """Flight modes, named as MAVSDK names PX4's."""

    UNKNOWN = "UNKNOWN"
    READY = "READY"
    TAKEOFF = "TAKEOFF"
    HOLD = "HOLD"
    MISSION = "MISSION"
    RETURN_TO_LAUNCH = "RETURN_TO_LAUNCH"
    LAND = "LAND"
    OFFBOARD = "OFFBOARD"
    FOLLOW_ME = "FOLLOW_ME"
    MANUAL = "MANUAL"
    ALTCTL = "ALTCTL"
    POSCTL = "POSCTL"
    ACRO = "ACRO"
    STABILIZED = "STABILIZED"
    RATTITUDE = "RATTITUDE"


@dataclass(frozen=True, slots=True)
class GeoPoint:
    """WGS-84 position. ``altitude_amsl_m`` above mean sea level."""

    latitude_deg: float
    longitude_deg: float
    altitude_amsl_m: float


@dataclass(frozen=True, slots=True)
class VehicleState:
    """A telemetry snapshot, stamped on receipt with the host monotonic clock.

    ``position_ned_m`` is the *estimate* the autopilot reports (relative to home);
    ``relative_altitude_m`` is height above home (positive up).
    """

    timestamp_ns: int
    position_ned_m: XYZ
    velocity_ned_mps: XYZ
    attitude_q: Quat  # body FRD -> NED, (w, x, y, z)
    angular_velocity_frd_radps: XYZ = (0.0, 0.0, 0.0)
    geodetic: GeoPoint | None = None
    relative_altitude_m: float = 0.0
    home: GeoPoint | None = None
    armed: bool = False
    in_air: bool = False
    flight_mode: FlightMode = FlightMode.UNKNOWN
    battery_remaining: float = 1.0  # 0..1
    battery_voltage_v: float = math.nan
    position_valid: bool = True
    gps_fix: bool = True
    link_ok: bool = True
    armable: bool = True
    # downward distance sensor (PX4 DISTANCE_SENSOR, MAVSDK Telemetry.distance_sensor): range
    # along the body's down axis to what lies below, metres; None without a sensor or out of range
    distance_to_ground_m: float | None = None
    # the autopilot's own stamp of the sample (MAVLink time_boot_ms / time_usec, ns since its
    # boot); None when the vehicle does not report it (eaglemission.telemetry.time_checks checks it)
    autopilot_time_ns: int | None = None

    @property
    def yaw_deg(self) -> float:
        w, x, y, z = self.attitude_q
        return math.degrees(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


@dataclass(frozen=True, slots=True)
class Setpoint:
    """An offboard position setpoint in local NED with yaw (MAVSDK's ``PositionNedYaw``)."""

    north_m: float
    east_m: float
    down_m: float
    yaw_deg: float

    def __post_init__(self) -> None:
        for name in ("north_m", "east_m", "down_m", "yaw_deg"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ValueError(f"Setpoint.{name}: must be finite, got {v}")

    @property
    def position_ned_m(self) -> XYZ:
        return (self.north_m, self.east_m, self.down_m)


@dataclass(frozen=True, slots=True)
class Waypoint:
    """A route point in local NED relative to home; ``altitude_m`` is above home (up)."""

    north_m: float
    east_m: float
    altitude_m: float
    speed_mps: float | None = None
    acceptance_radius_m: float = 1.0


@dataclass(frozen=True, slots=True)
class MissionProgress:
    current: int
    total: int

    @property
    def finished(self) -> bool:
        return self.total > 0 and self.current >= self.total


@dataclass(frozen=True, slots=True)
class VehicleEvent:
    """Something the vehicle reported or did: status text, mode change, failsafe, refusal."""

    timestamp_ns: int
    kind: str
    text: str
    data: dict[str, object] = field(default_factory=dict)


Shutter = Literal["global", "rolling"]
