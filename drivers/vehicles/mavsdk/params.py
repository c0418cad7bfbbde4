"""Parameters and the autopilot's version for the MAVSDK vehicle (MAVSDK Param and Info).

A parameter PX4 does not have is answered by a timeout or an error once; callers
(:mod:`eaglemission.safety.autopilot_guard`) ask each name once and report the missing ones.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

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
