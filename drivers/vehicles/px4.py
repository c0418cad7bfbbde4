"""PX4 facts: modes, flags, default parameters.

The lab's MAVLink emulator and autopilot model build on them. Pure data and small pure
functions; no I/O, no MAVLink library. Values were checked against the real PX4 v1.16 traffic
recorded in ``../shared/data/px4_sitl_tlogs`` (README there).
"""

from __future__ import annotations

import functools
import json
import struct
from pathlib import Path

from eaglemission.types import FlightMode

# PX4 ``px4_custom_mode``: main mode in bits 16..23, sub mode in bits 24..31.
MAIN_MANUAL, MAIN_ALTCTL, MAIN_POSCTL, MAIN_AUTO, MAIN_ACRO, MAIN_OFFBOARD, MAIN_STABILIZED = (
    1, 2, 3, 4, 5, 6, 7,
)
AUTO_READY, AUTO_TAKEOFF, AUTO_LOITER, AUTO_MISSION, AUTO_RTL, AUTO_LAND = 1, 2, 3, 4, 5, 6
POSCTL_ORBIT = 1
"""Position's sub mode while an orbit (DO_ORBIT) flies (probed: custom mode main 3, sub 1)."""

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
both cores (reports/px4_sitl.md; docs/faults.md)."""

# MAV_MODE_FLAG bits.
FLAG_CUSTOM_MODE = 1
FLAG_AUTO = 4
FLAG_GUIDED = 8
FLAG_STABILIZE = 16
FLAG_MANUAL_INPUT = 64
FLAG_ARMED = 128

MANUAL_MODES = frozenset({FlightMode.MANUAL, FlightMode.ALTCTL, FlightMode.POSCTL,
                          FlightMode.ACRO, FlightMode.STABILIZED})
"""Modes flown from the pilot's sticks (MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)."""
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


PARAMS_FILE = Path(__file__).with_name("px4_params_v1_16_sihsim_quadx.json")
"""PX4 v1.16's parameter set as the SIH quad (sihsim_quadx) reports it: 904 names, types and
values in PX4's order (its ``param_index``), imported from a running SITL by
``benchmarks/px4_params_import.py`` and checked against the build's parameter metadata."""
PX4_TYPES = {"INT32": PARAM_INT32, "REAL32": PARAM_REAL32}
MODELLED_PARAMS = frozenset({
    "MIS_TAKEOFF_ALT", "RTL_RETURN_ALT", "RTL_DESCEND_ALT", "RTL_CONE_ANG", "COM_OF_LOSS_T",
    "COM_OBL_RC_ACT", "COM_DL_LOSS_T", "NAV_DLL_ACT", "COM_DISARM_LAND", "COM_LOW_BAT_ACT",
    "BAT_LOW_THR", "BAT_CRIT_THR", "BAT_EMERGEN_THR", "MPC_XY_CRUISE", "MPC_XY_VEL_MAX",
    "MPC_VEL_MANUAL", "MPC_Z_VEL_MAX_UP", "MPC_Z_VEL_MAX_DN", "MPC_Z_V_AUTO_UP",
    "MPC_Z_V_AUTO_DN", "MPC_TKO_SPEED", "MPC_LAND_SPEED", "MPC_YAWRAUTO_MAX", "MPC_THR_HOVER",
    "NAV_ACC_RAD", "NAV_MC_ALT_RAD", "PD_GRIPPER_TO", "MC_ORBIT_RAD_MAX", "MAV_SYS_ID"})
"""The parameters the emulator's behaviour follows (the others are only reported)."""


@functools.cache
def default_params() -> dict[str, tuple[float, int]]:
    """PX4 v1.16's parameters, name -> (value, MAV_PARAM_TYPE), in PX4's order (read once from
    :data:`PARAMS_FILE`). MAV_SYS_ID is 1 there; the emulator reports its own system id."""
    with PARAMS_FILE.open(encoding="utf-8") as f:
        doc = json.load(f)
    return {str(name): (float(value), PX4_TYPES[ptype]) for name, ptype, value, _ in doc["params"]}
