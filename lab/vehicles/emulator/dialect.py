"""pymavlink's MAVLink 2 ``development`` dialect, loaded once for the emulator and its tests.

pymavlink ships no type information: the dialect is imported as a module object (its messages
and constants are typed ``Any``), in this one place. ``MAVLINK20`` must be set before
``mavutil`` is imported.
"""

from __future__ import annotations

import importlib
import math
import os
from types import ModuleType

os.environ.setdefault("MAVLINK20", "1")
mavutil: ModuleType = importlib.import_module("pymavlink.mavutil")  # reads MAVLINK20 at import
mavlink: ModuleType = importlib.import_module("pymavlink.dialects.v20.development")
M = mavlink

SENSORS: int = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                | M.MAV_SYS_STATUS_SENSOR_3D_MAG | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE)
GPS_BIT: int = M.MAV_SYS_STATUS_SENSOR_GPS
PREARM_BIT: int = M.MAV_SYS_STATUS_PREARM_CHECK

FENCE_COMMANDS: frozenset[int] = frozenset({
    M.MAV_CMD_NAV_FENCE_RETURN_POINT, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
    M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
    M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION})
NAV_COMMANDS: frozenset[int] = frozenset({
    M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_NAV_LOITER_TIME})
MISSION_DO: frozenset[int] = frozenset({
    M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_CMD_DO_GRIPPER, M.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
    M.MAV_CMD_DO_MOUNT_CONTROL, M.MAV_CMD_IMAGE_START_CAPTURE, M.MAV_CMD_IMAGE_STOP_CAPTURE,
    M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, M.MAV_CMD_NAV_DELAY})
"""DO items a mission may hold (run on arrival at the item before them)."""

SEVERITY: dict[str, int] = {"info": M.MAV_SEVERITY_INFO, "warning": M.MAV_SEVERITY_WARNING,
                            "critical": M.MAV_SEVERITY_CRITICAL}


def as_int(value: float, default: int = 0) -> int:
    """A MAVLink float param as an int (NaN means "not given")."""
    return int(value) if math.isfinite(value) else default
