"""COMMAND_LONG / COMMAND_INT and the parameter protocol of the MAVLink emulator, answered as
PX4 v1.16 answers MAVSDK 4.1 (recorded); accepted commands go to the shared autopilot model."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from eaglemission.drivers.vehicles import px4
from eaglemission.drivers.vehicles.autopilot_params import MANUAL_MODES, LandedState
from eaglemission.drivers.vehicles.emulator_config import (
    DISTANCE_SENSOR_MAX_HZ,
    HIL_STATE_DEFAULT_HZ,
    MSG_NAMES,
    PX4_ONBOARD_RATES_HZ,
)
from eaglemission.drivers.vehicles.emulator_manual import MANUAL_MODE_NAMES, ManualControlInput
from eaglemission.drivers.vehicles.mavlink_dialect import M, as_int

from eaglemission.geometry import geodetic_to_ned
from eaglemission.types import FlightMode, GeoPoint, Setpoint

if TYPE_CHECKING:  # the emulator owns its handlers; imported for the annotations only
    from eaglemission.drivers.vehicles.mavlink_emulator import Px4Emulator

log = logging.getLogger(__name__)

Handler = Callable[["CommandHandlers", Any, list[float], "int | None"], int]
CRITICAL = M.MAV_SEVERITY_CRITICAL


class CommandHandlers:
    """One method per MAV_CMD the emulator knows (:data:`COMMANDS`), returning MAV_RESULT."""

    def __init__(self, emulator: Px4Emulator) -> None:
        self._e = emulator
        self.deny: dict[int, int] = {}  # command id -> MAV_RESULT for the next one
        self.manual = ManualControlInput()
        self._first_set_mode_ack: int | None = None  # PX4's first of its two DO_SET_MODE acks

    def on_command_long(self, msg: Any) -> None:
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.param5, msg.param6, msg.param7], frame=None)

    def on_command_int(self, msg: Any) -> None:
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.x, msg.y, msg.z], frame=msg.frame)

    def _ack(self, msg: Any, command: int, result: int) -> None:
        self._e.emit(M.MAVLink_command_ack_message(command, result, 0, 0, msg.get_srcSystem(),
                                                   msg.get_srcComponent()))

    def _command(self, msg: Any, cmd: int, p: list[float], frame: int | None) -> None:
        denied = self.deny.pop(cmd, None)
        if denied is not None:
            self._ack(msg, cmd, denied)
            return
        handler = COMMANDS.get(cmd)
        if handler is None:
            self._ack(msg, cmd, M.MAV_RESULT_UNSUPPORTED)
            return
        try:
            result = handler(self, msg, p, frame)
        except Exception:  # PX4 answers every command: a bug here must not look like a TIMEOUT
            log.exception("emulator: command %d failed", cmd)
            result = M.MAV_RESULT_FAILED
        first, self._first_set_mode_ack = self._first_set_mode_ack, None
        if cmd == M.MAV_CMD_DO_SET_MODE and self._e.config.double_set_mode_ack:
            # PX4 v1.16 acknowledges DO_SET_MODE twice: the mode request is ACCEPTED, then
            # Commander's answer (recorded h1: ACCEPTED +3.7 ms, TEMPORARILY_REJECTED +7.7 ms)
            self._ack(msg, cmd, result if first is None else first)
        self._ack(msg, cmd, result)
        if result == M.MAV_RESULT_ACCEPTED and cmd == M.MAV_CMD_REQUEST_MESSAGE:
            self._e.send(MSG_NAMES.get(as_int(p[0], -1), ""))

    # ------------------------------------------------------------------------------------------
    def arm(self, msg: Any, p: list[float], frame: int | None) -> int:
        e, ap = self._e, self._e.autopilot
        force = as_int(p[1]) == 21196
        if p[0] >= 0.5:
            if ap.armed:
                return int(M.MAV_RESULT_ACCEPTED)
            if not force and not e.armable():
                e.statustext("Arming denied: preflight checks failed", CRITICAL)
                return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
            ap.arm()
            return int(M.MAV_RESULT_ACCEPTED)
        if not ap.armed:
            return int(M.MAV_RESULT_ACCEPTED)
        if ap.landed_state != LandedState.ON_GROUND and not force:
            e.statustext("Disarming denied: not landed", CRITICAL)
            return int(M.MAV_RESULT_DENIED)
        ap.disarm("Disarmed by external command")
        return int(M.MAV_RESULT_ACCEPTED)

    def takeoff(self, msg: Any, p: list[float], frame: int | None) -> int:
        e, ap = self._e, self._e.autopilot
        if not ap.armed:
            e.statustext("Takeoff denied! Please arm first", CRITICAL)
            return int(M.MAV_RESULT_DENIED)
        if not ap.gps_ok:
            return int(M.MAV_RESULT_DENIED)
        if math.isfinite(p[6]):
            alt = p[6] - e.home.altitude_amsl_m  # NAV_TAKEOFF param7 is AMSL
        else:
            alt = e.param("MIS_TAKEOFF_ALT")
            e.statustext(f"Using default takeoff altitude: {alt:.1f} m")
        ap.takeoff(max(alt, 0.5))
        return int(M.MAV_RESULT_ACCEPTED)

    def land(self, msg: Any, p: list[float], frame: int | None) -> int:
        if not self._e.autopilot.armed:
            return int(M.MAV_RESULT_DENIED)
        self._e.autopilot.land()
        self._e.statustext("Landing at current position")
        return int(M.MAV_RESULT_ACCEPTED)

    def rtl(self, msg: Any, p: list[float], frame: int | None) -> int:
        if not self._e.autopilot.armed:
            return int(M.MAV_RESULT_DENIED)
        self._e.autopilot.return_to_launch()
        return int(M.MAV_RESULT_ACCEPTED)

    def set_mode(self, msg: Any, p: list[float], frame: int | None) -> int:
        e, ap = self._e, self._e.autopilot
        if not (as_int(p[0]) & px4.FLAG_CUSTOM_MODE):
            return int(M.MAV_RESULT_UNSUPPORTED)
        main = as_int(p[1])
        mode = px4.PX4_TO_MODE.get((main, as_int(p[2]) if main == px4.MAIN_AUTO else 0))
        if mode is None:
            return int(M.MAV_RESULT_UNSUPPORTED)
        if mode == FlightMode.OFFBOARD and not ap.offboard_signal():
            e.statustext("Switching to Offboard is currently not available", CRITICAL)
            return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
        if mode == FlightMode.MISSION and not ap.mission.items:
            e.statustext("Switching to Mission is currently not available", CRITICAL)
            return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
        if mode in (FlightMode.TAKEOFF, FlightMode.LAND, FlightMode.RETURN_TO_LAUNCH) and not ap.armed:
            return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
        if mode in MANUAL_MODES and not self.manual.present(e.sim_time_s):
            # PX4 (COM_RC_IN_MODE 1, recorded h1): no MANUAL_CONTROL, no manual mode; the
            # vehicle stays in its mode (OFFBOARD kept following the setpoints)
            e.statustext(f"Switching to {MANUAL_MODE_NAMES[mode]} is currently not available", CRITICAL)
            self._first_set_mode_ack = int(M.MAV_RESULT_ACCEPTED)
            return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
        if mode == FlightMode.HOLD:
            ap.hold()
        elif mode in MANUAL_MODES:
            # the sticks decide (recorded h3: centred MANUAL_CONTROL, Position holds)
            ap.enter_manual(mode, "pilot")
            self.manual.apply(ap, e.param("MPC_VEL_MANUAL"), e.param("MPC_Z_VEL_MAX_UP"),
                              e.param("MPC_Z_VEL_MAX_DN"), force=True)
        elif mode == FlightMode.RETURN_TO_LAUNCH:
            ap.return_to_launch()
        elif mode == FlightMode.MISSION:
            ap.start_mission()
        elif mode == FlightMode.OFFBOARD:
            ap.enter_offboard()
        elif mode == FlightMode.LAND:
            ap.land()
        elif mode == FlightMode.TAKEOFF:
            ap.takeoff(e.param("MIS_TAKEOFF_ALT"))
        else:
            ap.set_mode(mode, "command")
        return int(M.MAV_RESULT_ACCEPTED)

    def reposition(self, msg: Any, p: list[float], frame: int | None) -> int:
        e, ap = self._e, self._e.autopilot
        if not ap.armed or ap.landed_state == LandedState.ON_GROUND:
            return int(M.MAV_RESULT_DENIED)
        if frame is None:  # COMMAND_LONG: degrees in params 5/6
            lat, lon, alt = p[4], p[5], p[6]
            frame = M.MAV_FRAME_GLOBAL
        else:
            lat, lon, alt = p[4] / 1e7, p[5] / 1e7, p[6]
        if frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            alt = e.home.altitude_amsl_m + alt
        here = e.dyn.estimate().position_ned_m
        if not (math.isfinite(lat) and math.isfinite(lon)):
            n, east = here[0], here[1]
        else:
            n, east, _ = geodetic_to_ned(e.home, GeoPoint(lat, lon, alt))
        d = e.home.altitude_amsl_m - alt if math.isfinite(alt) else here[2]
        yaw = math.degrees(p[3]) if math.isfinite(p[3]) else e.dyn.yaw_setpoint_deg
        ap.goto(Setpoint(n, east, d, yaw), p[0] if p[0] > 0 else None)
        return int(M.MAV_RESULT_ACCEPTED)

    def gripper(self, msg: Any, p: list[float], frame: int | None) -> int:
        action = as_int(p[1], -1)
        if action not in (M.GRIPPER_ACTION_RELEASE, M.GRIPPER_ACTION_GRAB):
            return int(M.MAV_RESULT_DENIED)
        ap = self._e.autopilot
        ap.gripper = "grab" if action == M.GRIPPER_ACTION_GRAB else "release"
        self._e.statustext(f"Gripper {ap.gripper}")
        return int(M.MAV_RESULT_ACCEPTED)

    def interval(self, msg: Any, p: list[float], frame: int | None) -> int:
        streams = self._e.streams
        name = MSG_NAMES.get(as_int(p[0], -1))
        if name is None or name not in streams.intervals:
            return int(M.MAV_RESULT_DENIED)
        ok = streams.set_interval(
            name, p[1], PX4_ONBOARD_RATES_HZ[name] or HIL_STATE_DEFAULT_HZ,
            DISTANCE_SENSOR_MAX_HZ if name == "DISTANCE_SENSOR" else None, time.monotonic())
        return int(M.MAV_RESULT_ACCEPTED if ok else M.MAV_RESULT_DENIED)

    def request(self, msg: Any, p: list[float], frame: int | None) -> int:
        return int(M.MAV_RESULT_ACCEPTED if as_int(p[0], -1) in MSG_NAMES else M.MAV_RESULT_DENIED)

    def change_speed(self, msg: Any, p: list[float], frame: int | None) -> int:
        self._e.autopilot.change_speed(p[1] if p[1] > 0 else None)
        return int(M.MAV_RESULT_ACCEPTED)

    def mission_start(self, msg: Any, p: list[float], frame: int | None) -> int:
        ap = self._e.autopilot
        if not ap.mission.items:
            return int(M.MAV_RESULT_DENIED)
        ap.start_mission(first=as_int(p[0]))
        return int(M.MAV_RESULT_ACCEPTED)

    def set_home(self, msg: Any, p: list[float], frame: int | None) -> int:
        return int(M.MAV_RESULT_ACCEPTED)  # home stays where the world is: accepted, ignored

    def on_manual_control(self, msg: Any) -> None:
        """MANUAL_CONTROL (a GCS's virtual sticks): what Position / Altitude / Manual follow."""
        e = self._e
        self.manual.on_message(msg, e.sim_time_s)
        if e.autopilot.mode in MANUAL_MODES and e.autopilot.manual_input:
            self.manual.apply(e.autopilot, e.param("MPC_VEL_MANUAL"), e.param("MPC_Z_VEL_MAX_UP"),
                              e.param("MPC_Z_VEL_MAX_DN"))

    def on_set_position_target_local_ned(self, msg: Any) -> None:
        """An offboard setpoint (position or velocity, local NED relative to the EKF origin)."""
        e = self._e
        if msg.coordinate_frame != M.MAV_FRAME_LOCAL_NED:
            return
        hl = e.home_local
        mask = msg.type_mask
        yaw = (None if mask & M.POSITION_TARGET_TYPEMASK_YAW_IGNORE or not math.isfinite(msg.yaw)
               else math.degrees(msg.yaw))
        ap = e.autopilot
        if not mask & (M.POSITION_TARGET_TYPEMASK_X_IGNORE | M.POSITION_TARGET_TYPEMASK_Y_IGNORE
                       | M.POSITION_TARGET_TYPEMASK_Z_IGNORE):
            if not all(math.isfinite(v) for v in (msg.x, msg.y, msg.z)):
                return  # PX4 rejects a non-finite position setpoint (it does not feed the signal)
            ap.set_setpoint(Setpoint(msg.x - hl[0], msg.y - hl[1], msg.z - hl[2],
                                     e.dyn.yaw_setpoint_deg if yaw is None else yaw))
        elif not mask & (M.POSITION_TARGET_TYPEMASK_VX_IGNORE | M.POSITION_TARGET_TYPEMASK_VY_IGNORE
                         | M.POSITION_TARGET_TYPEMASK_VZ_IGNORE):
            if not all(math.isfinite(v) for v in (msg.vx, msg.vy, msg.vz)):
                return
            ap.set_velocity_setpoint((msg.vx, msg.vy, msg.vz), yaw)
        else:
            return
        e.setpoint_wall = time.monotonic()

    # ------------------------------------------------------------------------------------------
    # parameters
    # ------------------------------------------------------------------------------------------
    def param_value(self, name: str) -> Any:
        e = self._e
        value, ptype = e.params[name]
        return M.MAVLink_param_value_message(name.encode(), px4.encode_param(float(value), int(ptype)),
                                             int(ptype), len(e.params), e.param_names.index(name))

    @staticmethod
    def _param_id(raw: Any) -> str:
        s = raw.decode(errors="ignore") if isinstance(raw, bytes) else str(raw)
        return s.split("\x00", 1)[0]

    def on_param_set(self, msg: Any) -> None:
        e = self._e
        name = self._param_id(msg.param_id)
        if name not in e.params:
            log.info("emulator: PARAM_SET of unknown parameter %s ignored", name)
            return
        e.set_param(name, px4.decode_param(msg.param_value, int(e.params[name][1])))
        e.emit(self.param_value(name))
        e.emit(self.param_value(name))  # PX4 answers PARAM_SET twice

    def on_param_request_read(self, msg: Any) -> None:
        e = self._e
        name = self._param_id(msg.param_id)
        if 0 <= msg.param_index < len(e.param_names) and not name:
            name = e.param_names[msg.param_index]
        if name in e.params:
            e.emit(self.param_value(name))

    def on_param_request_list(self, msg: Any) -> None:
        for name in self._e.param_names:
            self._e.emit(self.param_value(name))


COMMANDS: dict[int, Handler] = {
    M.MAV_CMD_COMPONENT_ARM_DISARM: CommandHandlers.arm,
    M.MAV_CMD_NAV_TAKEOFF: CommandHandlers.takeoff,
    M.MAV_CMD_NAV_LAND: CommandHandlers.land,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH: CommandHandlers.rtl,
    M.MAV_CMD_DO_SET_MODE: CommandHandlers.set_mode,
    M.MAV_CMD_DO_REPOSITION: CommandHandlers.reposition,
    M.MAV_CMD_DO_GRIPPER: CommandHandlers.gripper,
    M.MAV_CMD_SET_MESSAGE_INTERVAL: CommandHandlers.interval,
    M.MAV_CMD_REQUEST_MESSAGE: CommandHandlers.request,
    M.MAV_CMD_DO_CHANGE_SPEED: CommandHandlers.change_speed,
    M.MAV_CMD_MISSION_START: CommandHandlers.mission_start,
    M.MAV_CMD_DO_SET_HOME: CommandHandlers.set_home,
}
"""MAV_CMD -> handler."""
