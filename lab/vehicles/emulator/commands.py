"""COMMAND_LONG / COMMAND_INT and the parameter protocol of the MAVLink emulator, answered as
PX4 v1.16 answers MAVSDK 4.1 (recorded); accepted commands go to the shared autopilot model."""

from __future__ import annotations

import logging
import math
import struct
import time
import zlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal

from eaglemission.drivers.vehicles import px4
from eaglemission.lab.vehicles.autopilot import orbit as orbit_lib
from eaglemission.lab.vehicles.autopilot.params import LandedState
from eaglemission.lab.vehicles.emulator.config import (
    DISTANCE_SENSOR_MAX_HZ,
    HIL_STATE_DEFAULT_HZ,
    MSG_NAMES,
    PX4_ONBOARD_RATES_HZ,
)
from eaglemission.lab.vehicles.emulator.dialect import M, as_int
from eaglemission.lab.vehicles.emulator.manual import (
    MANUAL_MODE_NAMES,
    ManualControlInput,
    StickLimits,
)

from eaglemission.geometry import geodetic_to_ned
from eaglemission.types import FlightMode, GeoPoint, Setpoint

if TYPE_CHECKING:  # the emulator owns its handlers; imported for the annotations only
    from eaglemission.lab.vehicles.emulator.emulator import Px4Emulator

log = logging.getLogger(__name__)

Handler = Callable[["CommandHandlers", Any, list[float], "int | None"], int]
CRITICAL = M.MAV_SEVERITY_CRITICAL
INT32_MAX = 2**31 - 1
PARAM_ECHO_DELAY_S = 0.011
"""PX4's second PARAM_VALUE after a PARAM_SET (recorded a: 11 ms after the first)."""
MAV_RESULT_CANCELLED = 6  # MAVLink's value (not in pymavlink 2.4.50's development dialect)


def _global_of(p: list[float], frame: int | None) -> tuple[float, float, float]:
    """Latitude, longitude (degrees) and altitude of a command's params 5-7: COMMAND_LONG
    carries degrees, COMMAND_INT 1e7 integers (INT32_MAX, as PX4 reads it: not given)."""
    if frame is None:
        return p[4], p[5], p[6]
    lat = math.nan if p[4] == INT32_MAX else p[4] / 1e7
    lon = math.nan if p[5] == INT32_MAX else p[5] / 1e7
    return lat, lon, p[6]


class CommandHandlers:
    """One method per MAV_CMD the emulator knows (:data:`COMMANDS`), returning MAV_RESULT."""

    def __init__(self, emulator: Px4Emulator) -> None:
        self._e = emulator
        self.deny: dict[int, int] = {}  # command id -> MAV_RESULT for the next one
        self.manual = ManualControlInput()
        self.grip: tuple[Literal["grab", "release"], float, tuple[int, int]] | None = None
        """The gripper action under way: action, when it completes (emulator s), its sender."""
        self._param_echo: list[tuple[float, str]] = []  # PARAM_VALUE due again (wall s, name)
        self._first_set_mode_ack: int | None = None  # PX4's first of its two DO_SET_MODE acks

    def on_command_long(self, msg: Any) -> None:
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.param5, msg.param6, msg.param7], frame=None)

    def on_command_int(self, msg: Any) -> None:
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.x, msg.y, msg.z], frame=msg.frame)

    def _ack(self, msg: Any, command: int, result: int) -> None:
        # PX4 fills the progress of an IN_PROGRESS ack with 255 (unknown; probed, DO_GRIPPER)
        progress = 255 if result == M.MAV_RESULT_IN_PROGRESS else 0
        self._e.emit(M.MAVLink_command_ack_message(command, result, progress, 0,
                                                   msg.get_srcSystem(), msg.get_srcComponent()))

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
            if not force and ap.orbit is not None:
                # probed: DO_ORBIT accepted on the ground puts PX4 in Position's ORBIT, in which
                # it cannot be armed
                e.statustext("Arming denied: Resolve system health failures first", CRITICAL)
                return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
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
        """NAV_TAKEOFF. Disarmed, PX4 v1.16 ACCEPTs it and only selects Takeoff, without a
        status text (probed): arming then takes off."""
        e, ap = self._e, self._e.autopilot
        if not ap.gps_ok:
            return int(M.MAV_RESULT_DENIED)
        if math.isfinite(p[6]):
            alt = p[6] - e.home.altitude_amsl_m  # NAV_TAKEOFF param7 is AMSL
        else:
            alt = e.param("MIS_TAKEOFF_ALT")
            if ap.armed:
                e.statustext(f"Using default takeoff altitude: {alt:.1f} m")
        ap.takeoff(max(alt, 0.5))
        return int(M.MAV_RESULT_ACCEPTED)

    def land(self, msg: Any, p: list[float], frame: int | None) -> int:
        """NAV_LAND: ACCEPTED and Land, "Landing at current position", disarmed too (probed)."""
        self._e.autopilot.land()
        self._e.statustext("Landing at current position")
        return int(M.MAV_RESULT_ACCEPTED)

    def rtl(self, msg: Any, p: list[float], frame: int | None) -> int:
        """NAV_RETURN_TO_LAUNCH: Return; disarmed it is only selected (probed with DO_SET_MODE,
        which MAVSDK's return_to_launch sends: ACCEPTED, no status text)."""
        self._rtl()
        return int(M.MAV_RESULT_ACCEPTED)

    def _rtl(self) -> None:
        ap = self._e.autopilot
        if ap.armed:
            ap.return_to_launch()
        else:
            ap.set_mode(FlightMode.RETURN_TO_LAUNCH, "command")

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
        if mode in px4.MANUAL_MODES and not self.manual.present(e.sim_time_s):
            # PX4 (COM_RC_IN_MODE 1, recorded h1): no MANUAL_CONTROL, no manual mode; the
            # vehicle stays in its mode (OFFBOARD kept following the setpoints)
            e.statustext(f"Switching to {MANUAL_MODE_NAMES[mode]} is currently not available", CRITICAL)
            self._first_set_mode_ack = int(M.MAV_RESULT_ACCEPTED)
            return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
        if mode == FlightMode.HOLD:
            ap.hold()
        elif mode in px4.MANUAL_MODES:
            # the sticks decide (recorded h3: centred MANUAL_CONTROL, Position holds)
            ap.enter_manual(mode, "pilot")
            self.manual.apply(ap, self.stick_limits(), e.sim_time_s, force=True)
        elif mode == FlightMode.RETURN_TO_LAUNCH:
            self._rtl()  # disarmed: selected, ACCEPTED (probed; TEMPORARILY_REJECTED before)
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
        """DO_REPOSITION as PX4 v1.16 answers MAVSDK's ``goto_location`` (probed): param2 must
        ask for the mode change (MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, else UNSUPPORTED); then
        ACCEPTED and Hold, disarmed too (nothing flies); armed on the ground it takes off to
        the target, right after a takeoff command (0.2 s, still on the ground) it climbs and
        flies there."""
        e, ap = self._e, self._e.autopilot
        flags = as_int(p[1])
        if not flags & M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE or flags & ~M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE:
            return int(M.MAV_RESULT_UNSUPPORTED)
        if not ap.armed:
            ap.hold()
            return int(M.MAV_RESULT_ACCEPTED)
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
        """DO_GRIPPER as PX4 v1.16's payload deliverer answers it (probed): a change of state is
        IN_PROGRESS (progress 255) at once and ACCEPTED PD_GRIPPER_TO (1 s) later; the state it
        is already in, ACCEPTED at once; the same action while it is under way,
        TEMPORARILY_REJECTED; the other one, CANCELLED to the first command's sender and
        IN_PROGRESS. PX4 grabs at boot. No status text."""
        e = self._e
        action = as_int(p[1], -1)
        if action not in (M.GRIPPER_ACTION_RELEASE, M.GRIPPER_ACTION_GRAB):
            return int(M.MAV_RESULT_DENIED)
        want: Literal["grab", "release"] = "grab" if action == M.GRIPPER_ACTION_GRAB else "release"
        g = self.grip
        if g is not None:
            if g[0] == want:
                return int(M.MAV_RESULT_TEMPORARILY_REJECTED)
            self._e.emit(M.MAVLink_command_ack_message(M.MAV_CMD_DO_GRIPPER, MAV_RESULT_CANCELLED,
                                                       0, 0, g[2][0], g[2][1]))
            self.grip = None
        elif e.autopilot.gripper == want:
            return int(M.MAV_RESULT_ACCEPTED)
        self.grip = (want, e.sim_time_s + e.param("PD_GRIPPER_TO"),
                     (msg.get_srcSystem(), msg.get_srcComponent()))
        return int(M.MAV_RESULT_IN_PROGRESS)

    def tick(self) -> None:
        """Late answers: PARAM_SET's second PARAM_VALUE (wall time), a gripper action's final
        ACCEPTED (emulator time)."""
        if self._param_echo and self._param_echo[0][0] <= time.monotonic():
            now = time.monotonic()
            due = [n for t, n in self._param_echo if t <= now]
            self._param_echo = [(t, n) for t, n in self._param_echo if t > now]
            for name in due:
                self._e.emit(self.param_value(name))
        g = self.grip
        if g is not None and self._e.sim_time_s >= g[1]:
            self.grip = None
            self._e.autopilot.gripper = g[0]
            self._e.emit(M.MAVLink_command_ack_message(M.MAV_CMD_DO_GRIPPER, M.MAV_RESULT_ACCEPTED,
                                                       0, 0, g[2][0], g[2][1]))

    def orbit(self, msg: Any, p: list[float], frame: int | None) -> int:
        """DO_ORBIT (MAVSDK's ``Action.do_orbit`` sends it as COMMAND_INT): ACCEPTED, Position
        mode's ORBIT (probed on PX4 v1.16), disarmed on the ground too (then arming is denied
        until another mode is selected); see :mod:`.autopilot_orbit`."""
        e, ap = self._e, self._e.autopilot
        radius = p[0] if math.isfinite(p[0]) else (ap.orbit.radius_m if ap.orbit else math.nan)
        if not (orbit_lib.RADIUS_MIN_M <= abs(radius) <= e.param("MC_ORBIT_RAD_MAX")):
            e.statustext("Orbit radius limit exceeded", CRITICAL)
            ap.hold()
            return int(M.MAV_RESULT_ACCEPTED)  # PX4's Commander accepts; its orbit task refuses
        speed = abs(p[1]) if math.isfinite(p[1]) else 1.0
        speed = orbit_lib.sanitized_speed(abs(radius), speed if radius > 0 else -speed)
        here = e.dyn.estimated_position()
        lat, lon, alt = _global_of(p, frame)
        if math.isfinite(lat) and math.isfinite(lon):
            cn, ce, _ = geodetic_to_ned(e.home, GeoPoint(lat, lon, e.home.altitude_amsl_m))
        else:
            cn, ce = here[0], here[1]
        if math.isfinite(alt):
            rel = frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
            down = -alt if rel else e.home.altitude_amsl_m - alt
        else:
            down = here[2]
        yaw_mode = as_int(p[2], int(e.param("MC_ORBIT_YAW_MOD")))
        if yaw_mode == 5:  # ORBIT_YAW_BEHAVIOUR_UNCHANGED
            yaw_mode = ap.orbit.yaw_behaviour if ap.orbit else int(e.param("MC_ORBIT_YAW_MOD"))
        ap.start_orbit(orbit_lib.Orbit((cn, ce), down, abs(radius), speed, yaw_mode,
                                       e.dyn.yaw_deg, e.dyn.time_ns))
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
        if e.autopilot.mode in px4.MANUAL_MODES and e.autopilot.manual_input:
            self.manual.apply(e.autopilot, self.stick_limits(), e.sim_time_s)

    def stick_limits(self) -> StickLimits:
        p = self._e.param
        return StickLimits(p("MPC_VEL_MANUAL"), p("MPC_ACC_HOR"), p("MPC_XY_MAN_EXPO"),
                           p("MPC_Z_VEL_MAX_UP"), p("MPC_Z_VEL_MAX_DN"), p("MPC_Z_MAN_EXPO"))

    # ------------------------------------------------------------------------------------------
    # parameters
    # ------------------------------------------------------------------------------------------
    def param_value(self, name: str) -> Any:
        e = self._e
        value, ptype = e.params[name]
        return M.MAVLink_param_value_message(name.encode(), px4.encode_param(float(value), int(ptype)),
                                             int(ptype), len(e.params), e.param_index[name])

    @staticmethod
    def _param_id(raw: Any) -> str:
        s = raw.decode(errors="ignore") if isinstance(raw, bytes) else str(raw)
        return s.split("\x00", 1)[0]

    def on_param_set(self, msg: Any) -> None:
        """PARAM_SET as PX4 v1.16 answers it (probed, benchmarks/probe_mavsdk_plugins.py): an
        unknown name or a type other than the parameter's own is not answered at all (PX4 only
        logs it on its console; MAVSDK retries 6 times and reports TIMEOUT after ~3 s), else the
        value twice (recorded a: the second 11 ms later)."""
        e = self._e
        name = self._param_id(msg.param_id)
        if name not in e.params:
            log.info("emulator: PARAM_SET of unknown parameter %s ignored (as PX4)", name)
            return
        ptype = int(e.params[name][1])
        if int(msg.param_type) != ptype:
            log.info("emulator: PARAM_SET %s with type %s, not %s: ignored (as PX4)", name,
                     msg.param_type, ptype)
            return
        e.set_param(name, px4.decode_param(msg.param_value, ptype))
        e.emit(self.param_value(name))
        # PX4 answers PARAM_SET twice, the second time when the parameter-change notification
        # goes round (recorded a: 11 ms later; probed: MAVSDK, setting the next parameter with
        # another type, took that late answer for its own and returned WRONG_TYPE)
        self._param_echo.append((time.monotonic() + PARAM_ECHO_DELAY_S, name))

    def on_param_request_read(self, msg: Any) -> None:
        e = self._e
        name = self._param_id(msg.param_id)
        if 0 <= msg.param_index < len(e.param_names) and not name:
            name = e.param_names[msg.param_index]
        if name in e.params:
            e.emit(self.param_value(name))

    def on_param_request_list(self, msg: Any) -> None:
        """The whole list in PX4's order, after PX4's ``_HASH_CHECK`` (index -1, UINT32: a
        checksum of the set a ground station may cache the list by)."""
        e = self._e
        e.emit(M.MAVLink_param_value_message(
            b"_HASH_CHECK", struct.unpack("<f", struct.pack("<I", self.params_hash()))[0],
            M.MAV_PARAM_TYPE_UINT32, len(e.params), 65535))
        for name in e.param_names:
            e.emit(self.param_value(name))

    def params_hash(self) -> int:
        """CRC-32 of the names and values (PX4 computes its own over the same; only the value
        changing with the set matters to a client)."""
        e = self._e
        return zlib.crc32("".join(f"{k}={v[0]!r};" for k, v in e.params.items()).encode())


COMMANDS: dict[int, Handler] = {
    M.MAV_CMD_COMPONENT_ARM_DISARM: CommandHandlers.arm,
    M.MAV_CMD_NAV_TAKEOFF: CommandHandlers.takeoff,
    M.MAV_CMD_NAV_LAND: CommandHandlers.land,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH: CommandHandlers.rtl,
    M.MAV_CMD_DO_SET_MODE: CommandHandlers.set_mode,
    M.MAV_CMD_DO_REPOSITION: CommandHandlers.reposition,
    M.MAV_CMD_DO_GRIPPER: CommandHandlers.gripper,
    M.MAV_CMD_DO_ORBIT: CommandHandlers.orbit,
    M.MAV_CMD_SET_MESSAGE_INTERVAL: CommandHandlers.interval,
    M.MAV_CMD_REQUEST_MESSAGE: CommandHandlers.request,
    M.MAV_CMD_DO_CHANGE_SPEED: CommandHandlers.change_speed,
    M.MAV_CMD_MISSION_START: CommandHandlers.mission_start,
    M.MAV_CMD_DO_SET_HOME: CommandHandlers.set_home,
}
"""MAV_CMD -> handler."""
