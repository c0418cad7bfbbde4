"""Arming, re-arming and landing of the MAVSDK vehicle around PX4's auto-disarm, and the
request for the simulator's ground truth made at connect.

PX4 disarms a landed vehicle by itself (COM_DISARM_LAND 2.02 s after "Landing detected", which
comes 3.2-6.9 s after touchdown; COM_DISARM_PRFLT without a takeoff; recorded in
../shared/data/px4_sitl_tlogs, scenario e), and an ARM command while armed changes nothing (PX4
answers ACCEPTED and keeps its timer), so a takeoff started then is disarmed mid-climb unless
PX4 detects the takeoff first. These functions make every such wait bounded and named.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import TYPE_CHECKING, Any

from eaglemission.drivers.vehicles.events import EVENT_STATUS
from eaglemission.drivers.vehicles.mavsdk.hil_truth import MSG_ID as HIL_MSG_ID

from eaglemission.errors import TimeoutError_, VehicleError
from eaglemission.types import FlightMode

if TYPE_CHECKING:  # the vehicle calls these with itself; imported for the annotations only
    from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle

log = logging.getLogger(__name__)
MAV_CMD_SET_MESSAGE_INTERVAL = 511
TAKEOFF_PARAM_SETTLE_S = 1.0
"""From a changed MIS_TAKEOFF_ALT to the takeoff command (PX4's navigator loop runs at
>= 20 Hz; the margin covers a loaded SITL)."""


async def arm(v: MavsdkVehicle) -> None:
    """Arm, and wait (bounded) until the HEARTBEAT shows it. Already armed *on the ground* is
    not ready: the vehicle is disarmed explicitly (it is landed) and armed again. Already armed
    in the air: nothing to do."""
    v._require("arm()")
    c = v._c
    if c.armed and not c.in_air:
        await disarm_landed(v, "arm()")
    if not c.armed and c.mode == FlightMode.OFFBOARD:
        # disarmed after an offboard flight, PX4 shows OFFBOARD again (the last mode the user
        # selected, recorded b/f/g/i) and fails its arming checks without a setpoint stream
        # ("No offboard signal"): select HOLD first (harmless on the ground)
        await v.mode_command("arm()", v.plugins["Action"].hold, {FlightMode.HOLD})
    await v.bounded("arm()", v.plugins["Action"].arm)
    await v._confirm("arm()", lambda: v._c.armed, "armed")


async def disarm_landed(v: MavsdkVehicle, origin: str) -> None:
    """Armed and landed (``in_air`` False): disarm (PX4 accepts it on the ground) and wait for
    the disarmed HEARTBEAT."""
    log.info("%s: armed on the ground (mode %s): disarming first so that PX4's auto-disarm "
             "cannot hit the next takeoff", origin, v._c.mode.value)
    v.event(EVENT_STATUS, f"{origin}: armed on the ground: disarm before arming again",
            {"mode": v._c.mode.value})
    await v.bounded(origin, v.plugins["Action"].disarm)
    await v._confirm(origin, lambda: not v._c.armed,
                     "disarmed (explicit disarm of a landed vehicle before re-arming)")


async def rearm_after_landing(v: MavsdkVehicle, origin: str) -> None:
    """Armed on the ground right after a landing (LAND / RTL): disarm and arm again, so that
    PX4's auto-disarm timer cannot cut the motors during the next climb."""
    await disarm_landed(v, origin)
    await v.bounded(origin, v.plugins["Action"].arm)
    await v._confirm(origin, lambda: v._c.armed, "armed (re-armed after a landing)")


async def wait_landed_and_disarmed(v: MavsdkVehicle, land_timeout_s: float = 60.0) -> None:
    """After a land (or RTL): wait (bounded, ``land_timeout_s``) until touchdown is reported
    (``in_air`` False), then up to ``disarm_after_landing_timeout_s`` for PX4's own auto-disarm,
    then disarm explicitly if it is still armed. Returns disarmed; a timeout names the stage it
    was in."""
    v._require("wait_landed_and_disarmed()")
    origin = "wait_landed_and_disarmed()"
    c = v._c
    deadline = time.monotonic() + land_timeout_s
    while c.in_air:
        if time.monotonic() > deadline:
            raise TimeoutError_(origin, land_timeout_s,
                                f"still in the air after {land_timeout_s:g} s (mode="
                                f"{c.mode.value} armed={c.armed}): landing not detected")
        await asyncio.sleep(0.05)
    wait_s = v.config.disarm_after_landing_timeout_s
    deadline = time.monotonic() + wait_s
    while c.armed and not c.in_air and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    if c.in_air:
        raise VehicleError("NOT_LANDED", origin, None,
                           f"in the air again while waiting for the disarm (mode={c.mode.value})")
    if c.armed:
        log.info("%s: no auto-disarm within %.1f s of touchdown: disarming", origin, wait_s)
        await v.bounded(origin, v.plugins["Action"].disarm)
        await v._confirm(origin, lambda: not c.armed,
                         f"disarmed (explicit disarm, no auto-disarm within {wait_s:g} s of "
                         "touchdown)")


async def request_truth(v: MavsdkVehicle) -> None:
    """MAV_CMD_SET_MESSAGE_INTERVAL(HIL_STATE_QUATERNION): PX4 SIH streams its ground truth only
    when asked; a refusal (a real aircraft) is not an error."""
    if v.ground_truth() is None:
        return
    try:  # to the connected autopilot's own system id (it wrote 1, which MAVSDK's
        # MavlinkDirect replaced with its system's id on the wire: not to be relied on)
        result = await v.session.command_long(
            "request ground truth", MAV_CMD_SET_MESSAGE_INTERVAL,
            [float(HIL_MSG_ID), 1e6 / v.config.ground_truth_rate_hz])
    except VehicleError as exc:
        log.info("no ground-truth stream requested: %s", exc)
        return
    if result != 0:
        log.info("no ground-truth stream: the autopilot answered MAV_RESULT %d", result)


async def set_takeoff_altitude(v: MavsdkVehicle, act: Any, altitude_m: float) -> None:
    """MIS_TAKEOFF_ALT set (when it differs) and read back, then :data:`TAKEOFF_PARAM_SETTLE_S`
    before the takeoff command: PX4's navigator reads the parameter on its own loop, and a
    takeoff sent right after the set climbed to the old value on PX4 + jMAVSim ("Using
    default takeoff altitude: 2.5 m", the mission's TAKEOFF timed out). A second try, then a
    refusal naming the parameter."""
    got = await v.get_param("MIS_TAKEOFF_ALT")
    if abs(got - altitude_m) < 0.05:
        return
    for _ in range(2):
        await v.bounded("takeoff()", lambda: act.set_takeoff_altitude(altitude_m),
                        params=(altitude_m,))
        got = await v.get_param("MIS_TAKEOFF_ALT")
        if abs(got - altitude_m) < 0.05:
            await v.clock.sleep(TAKEOFF_PARAM_SETTLE_S)
            return
        log.warning("takeoff(): MIS_TAKEOFF_ALT reads %.2f m after setting %.2f m: again",
                    got, altitude_m)
    raise VehicleError("PARAM_NOT_SET", "takeoff()", (altitude_m,),
                       f"MIS_TAKEOFF_ALT reads {got:.2f} m after setting it to "
                       f"{altitude_m:.2f} m twice: not taking off to an unknown height")
