"""Parameters, the geofence and the autopilot's version for the MAVSDK vehicle (MAVSDK Param,
Geofence and Info).

A parameter PX4 does not have is answered by a timeout or an error once; callers
(:mod:`eaglemission.safety.autopilot_guard`) ask each name once and report the missing ones.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from eaglemission.drivers.vehicles.events import EVENT_STATUS
from eaglemission.drivers.vehicles.mavsdk.support import geofence_data

from eaglemission.config import GeofenceConfig
from eaglemission.errors import VehicleError

if TYPE_CHECKING:  # the vehicle calls these with itself; imported for the annotations only
    from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle


async def get_param(v: MavsdkVehicle, name: str) -> float:
    """A float parameter, else an int one (PX4 answers WRONG_TYPE for the other)."""
    v._require("get_param()")
    p = v.plugins["Param"]
    try:
        return float(await v.bounded("get_param()", lambda: p.get_param_float(name),
                                     params=name))
    except VehicleError as exc:
        if exc.result != "WRONG_TYPE":
            raise
    return float(await v.bounded("get_param()", lambda: p.get_param_int(name), params=name))


async def set_param_int(v: MavsdkVehicle, name: str, value: int) -> None:
    """Write an integer parameter (PX4's ``PWM_MAIN_FUNCn``, ``COM_PREARM_MODE``): PX4 ignores
    a float write to an int parameter, which MAVSDK then reports as a timeout."""
    v._require("set_param_int()")
    p = v.plugins["Param"]
    await v.bounded("set_param_int()", lambda: p.set_param_int(name, int(value)),
                    params=(name, value))


async def autopilot_version(v: MavsdkVehicle) -> dict[str, Any]:
    """PX4's version, git hash and release type (MAVSDK Info.get_version: AUTOPILOT_VERSION)."""
    v._require("autopilot_version()")
    ver = await v.bounded("autopilot_version()", v.plugins["Info"].get_version)
    h = ver.flight_sw_git_hash
    kind = ver.flight_sw_version_type
    return {"flight_sw_version": f"{ver.flight_sw_major}.{ver.flight_sw_minor}."
                                 f"{ver.flight_sw_patch}",
            "flight_sw_git_hash": h.decode() if isinstance(h, bytes) else str(h),
            "flight_sw_version_type": getattr(kind, "name", str(kind))}


async def upload_geofence(v: MavsdkVehicle, geofence: GeofenceConfig) -> None:
    """Upload the envelope's geofence (a circle around home or a NED polygon) as PX4's
    inclusion fence; PX4 then enforces it itself (its GF_ACTION)."""
    v._require("upload_geofence()")
    home = await v._home("upload_geofence()")
    if home is None:
        raise VehicleError("NO_HOME", "upload_geofence()", None,
                           "home is not known yet: wait for telemetry (GPS fix)")
    data, circles, polygons = geofence_data(v.mavsdk, home, geofence)
    gf = v.plugins["Geofence"]
    await v.bounded("upload_geofence()", lambda: gf.upload_geofence(data),
                    timeout_s=v.config.mission_upload_timeout_s)
    v.event(EVENT_STATUS, "geofence uploaded", {"circles": circles, "polygons": polygons})
