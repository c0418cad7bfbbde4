"""PX4 facts shared by the MAVLink emulator and its tests: modes, flags, default parameters.

Pure data and small pure functions; no I/O, no MAVLink library. Values were checked against
the real PX4 v1.16 traffic recorded in ``../shared/data/px4_sitl_tlogs`` (README there).
"""

from __future__ import annotations

import struct

from eaglemission.types import FlightMode

# PX4 ``px4_custom_mode``: main mode in bits 16..23, sub mode in bits 24..31.
MAIN_MANUAL, MAIN_ALTCTL, MAIN_POSCTL, MAIN_AUTO, MAIN_ACRO, MAIN_OFFBOARD, MAIN_STABILIZED = (
    1, 2, 3, 4, 5, 6, 7,
)
AUTO_READY, AUTO_TAKEOFF, AUTO_LOITER, AUTO_MISSION, AUTO_RTL, AUTO_LAND = 1, 2, 3, 4, 5, 6

MODE_TO_PX4: dict[FlightMode, tuple[int, int]] = {
    FlightMode.MANUAL: (MAIN_MANUAL, 0),
    FlightMode.ALTCTL: (MAIN_ALTCTL, 0),
    FlightMode.POSCTL: (MAIN_POSCTL, 0),
    FlightMode.READY: (MAIN_AUTO, AUTO_READY),
    FlightMode.TAKEOFF: (MAIN_AUTO, AUTO_TAKEOFF),
    FlightMode.HOLD: (MAIN_AUTO, AUTO_LOITER),
    FlightMode.MISSION: (MAIN_AUTO, AUTO_MISSION),
    FlightMode.RETURN_TO_LAUNCH: (MAIN_AUTO, AUTO_RTL),
    FlightMode.LAND: (MAIN_AUTO, AUTO_LAND),
    FlightMode.ACRO: (MAIN_ACRO, 0),
    FlightMode.OFFBOARD: (MAIN_OFFBOARD, 0),
    FlightMode.STABILIZED: (MAIN_STABILIZED, 0),
}
PX4_TO_MODE: dict[tuple[int, int], FlightMode] = {v: k for k, v in MODE_TO_PX4.items()}

PX4_SITL_CLOCK_RATE = 0.992
"""PX4 SITL's clock against the host's: its stamps advance 0.65-1.6 % less than the recording
host's clock (recorded fact 22); a local SITL build here ran 2 % slow while the mission loaded
both cores (docs/vehicles.md, "Against a real PX4 SITL"; docs/faults.md)."""

# MAV_MODE_FLAG bits.
FLAG_CUSTOM_MODE = 1
FLAG_AUTO = 4
FLAG_GUIDED = 8
FLAG_STABILIZE = 16
FLAG_MANUAL_INPUT = 64
FLAG_ARMED = 128

MANUAL_MODES = frozenset({FlightMode.MANUAL, FlightMode.ALTCTL, FlightMode.POSCTL,
                          FlightMode.ACRO, FlightMode.STABILIZED})
AUTO_MODES = frozenset({FlightMode.READY, FlightMode.TAKEOFF, FlightMode.HOLD,
                        FlightMode.MISSION, FlightMode.RETURN_TO_LAUNCH, FlightMode.LAND})


def custom_mode(mode: FlightMode) -> int:
    """HEARTBEAT ``custom_mode`` of a flight mode (``(sub << 24) | (main << 16)``)."""
    main, sub = MODE_TO_PX4[mode]
    return (sub << 24) | (main << 16)


def decode_custom_mode(value: int) -> FlightMode:
    """Flight mode of a HEARTBEAT ``custom_mode``; UNKNOWN for modes we do not model."""
    main = (value >> 16) & 0xFF
    sub = (value >> 24) & 0xFF
    if main != MAIN_AUTO:
        sub = 0
    return PX4_TO_MODE.get((main, sub), FlightMode.UNKNOWN)


def base_mode(mode: FlightMode, armed: bool) -> int:
    """HEARTBEAT ``base_mode`` as PX4 v1.16 reports it.

    Recorded: disarmed Hold 0x1d, armed Mission 0x9d, armed Offboard 0x91, armed Position 0xd1.
    """
    flags = FLAG_CUSTOM_MODE | FLAG_STABILIZE
    if mode in AUTO_MODES:
        flags |= FLAG_AUTO | FLAG_GUIDED
    elif mode in MANUAL_MODES:
        flags |= FLAG_MANUAL_INPUT
    if armed:
        flags |= FLAG_ARMED
    return flags


# PARAM types (MAV_PARAM_TYPE) and PX4's bytewise encoding of integers.
PARAM_INT32 = 6
PARAM_REAL32 = 9


def encode_param(value: float, param_type: int) -> float:
    """PARAM_VALUE.param_value for a value: INT32 carries the integer's bit pattern."""
    if param_type == PARAM_INT32:
        return float(struct.unpack("<f", struct.pack("<i", int(value)))[0])
    return float(value)


def decode_param(raw: float, param_type: int) -> float:
    """Inverse of :func:`encode_param`."""
    if param_type == PARAM_INT32:
        return float(struct.unpack("<i", struct.pack("<f", raw))[0])
    return float(raw)


PX4_VERSION = (1, 16, 0)
PX4_GIT_HASH = "6ea3539157ca358c70a515878b77077af7d4611d"
"""The PX4 release the emulator answers AUTOPILOT_VERSION as (recorded: v1.16.0 at this
commit; flight_sw_version 0x011000FF, flight_custom_version the hash's first bytes)."""


def flight_sw_version(version: tuple[int, int, int] = PX4_VERSION) -> int:
    """AUTOPILOT_VERSION.flight_sw_version: major, minor, patch, 0xFF (official release)."""
    return (version[0] << 24) | (version[1] << 16) | (version[2] << 8) | 0xFF


def custom_version_bytes(git_hash: str = PX4_GIT_HASH) -> list[int]:
    """AUTOPILOT_VERSION.flight_custom_version as PX4 sends it: the hash's first 5 bytes,
    most significant last (recorded: [0, 0, 0, 0x57, 0x91, 0x53, 0xa3, 0x6e])."""
    head = bytes.fromhex(git_hash[:10])
    return [0, 0, 0, *reversed(head)]


# The parameters the emulator models (PX4 v1.16 defaults; MIS_TAKEOFF_ALT etc. are what MAVSDK
# touches, COM_* are the failsafe settings a mission should read back before flying).
DEFAULT_PARAMS: dict[str, tuple[float, int]] = {
    "MIS_TAKEOFF_ALT": (2.5, PARAM_REAL32),
    # RTL heights as PX4 v1.16's multicopter airframes set them (sihsim_quadx, recorded d-i:
    # 30 / 10 m; the parameters' own defaults are 60 / 30 m)
    "RTL_RETURN_ALT": (30.0, PARAM_REAL32),
    "RTL_DESCEND_ALT": (10.0, PARAM_REAL32),
    "COM_OF_LOSS_T": (1.0, PARAM_REAL32),
    "COM_OBL_RC_ACT": (0, PARAM_INT32),  # 0 Position, 1 Altitude, 2 Manual, 3 Return, 4 Land, 5 Hold
    "COM_DL_LOSS_T": (10.0, PARAM_REAL32),
    "NAV_DLL_ACT": (0, PARAM_INT32),  # 0 none, 1 hold, 2 return, 3 land
    "NAV_RCL_ACT": (2, PARAM_INT32),  # RC loss: 2 return (reported only: no RC is emulated)
    "COM_RC_IN_MODE": (1, PARAM_INT32),  # reported only (recorded d-i: 1, MAVLink only)
    "GF_ACTION": (2, PARAM_INT32),  # geofence breach: 2 hold (reported only: no PX4 geofence)
    "COM_DISARM_LAND": (2.0, PARAM_REAL32),
    "COM_LOW_BAT_ACT": (0, PARAM_INT32),  # 0 warning, 2 land, 3 return at critical
    "BAT_LOW_THR": (0.15, PARAM_REAL32),
    "BAT_CRIT_THR": (0.07, PARAM_REAL32),
    "BAT_EMERGEN_THR": (0.05, PARAM_REAL32),
    "COM_POS_FS_DELAY": (1.0, PARAM_REAL32),
    "MPC_XY_CRUISE": (5.0, PARAM_REAL32),
    "MPC_XY_VEL_MAX": (12.0, PARAM_REAL32),
    "MPC_VEL_MANUAL": (10.0, PARAM_REAL32),  # Position mode, sticks at full deflection
    "MPC_Z_VEL_MAX_UP": (3.0, PARAM_REAL32),
    "MPC_Z_VEL_MAX_DN": (1.5, PARAM_REAL32),
    "MPC_Z_V_AUTO_UP": (3.0, PARAM_REAL32),  # autopilot-flown climbs (RTL, missions)
    "MPC_Z_V_AUTO_DN": (1.5, PARAM_REAL32),
    "MPC_ACC_HOR": (3.0, PARAM_REAL32),
    "MPC_XY_P": (0.95, PARAM_REAL32),
    "RTL_CONE_ANG": (45, PARAM_INT32),
    "RTL_MIN_DIST": (10.0, PARAM_REAL32),
    "RTL_LAND_DELAY": (0.0, PARAM_REAL32),
    "RTL_TYPE": (0, PARAM_INT32),
    "COM_RC_OVERRIDE": (1, PARAM_INT32),
    "COM_FAIL_ACT_T": (5.0, PARAM_REAL32),
    "COM_SPOOLUP_TIME": (1.0, PARAM_REAL32),
    "MPC_TKO_SPEED": (1.5, PARAM_REAL32),
    "MPC_LAND_SPEED": (0.7, PARAM_REAL32),
    "MPC_YAWRAUTO_MAX": (45.0, PARAM_REAL32),
    "NAV_ACC_RAD": (2.0, PARAM_REAL32),
    "NAV_MC_ALT_RAD": (0.8, PARAM_REAL32),
    "SYS_AUTOSTART": (10040, PARAM_INT32),
}
