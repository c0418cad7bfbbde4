"""The mission and geofence protocol of the MAVLink emulator (upload item by item with
retries, download, clear, set current), as PX4 v1.16 runs it (recorded scenario c); uploaded
missions become the shared autopilot model's :class:`~.autopilot_mission.MissionItem` s."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from eaglemission.lab.vehicles.autopilot.mission import MissionItem
from eaglemission.lab.vehicles.autopilot.params import LandedState
from eaglemission.lab.vehicles.emulator.dialect import (
    FENCE_COMMANDS,
    MISSION_DO,
    NAV_COMMANDS,
    M,
)

from eaglemission.geometry import geodetic_to_ned
from eaglemission.types import XYZ, FlightMode, GeoPoint

if TYPE_CHECKING:  # the emulator owns the protocol; imported for the annotations only
    from eaglemission.lab.vehicles.emulator.emulator import Px4Emulator

_GLOBAL = frozenset({M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                     M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL})
_RELATIVE = frozenset({M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT})


def mission_item(it: Any, home: GeoPoint, home_local: XYZ) -> MissionItem:
    """The autopilot's item for one MISSION_ITEM_INT (positions relative to home; a global
    item at lat = lon = 0 is flown where the vehicle is)."""
    cmd = it.command
    if cmd not in NAV_COMMANDS:
        if cmd == M.MAV_CMD_DO_CHANGE_SPEED:
            return MissionItem("speed", speed_mps=it.param2 if it.param2 > 0 else None)
        if cmd == M.MAV_CMD_DO_GRIPPER:
            return MissionItem("gripper", grab=int(it.param2) == M.GRIPPER_ACTION_GRAB)
        return MissionItem("other")
    if cmd == M.MAV_CMD_NAV_LAND:
        return MissionItem("land")
    if cmd == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        return MissionItem("return")
    north: float | None = None
    east: float | None = None
    alt: float | None = None
    if it.frame in _GLOBAL:
        amsl = home.altitude_amsl_m + it.z if it.frame in _RELATIVE else it.z
        alt = amsl - home.altitude_amsl_m
        if not (it.x == 0 and it.y == 0):
            north, east, d = geodetic_to_ned(home, GeoPoint(it.x / 1e7, it.y / 1e7, amsl))
            alt = -d
    elif it.frame == M.MAV_FRAME_LOCAL_NED:
        north, east, alt = it.x - home_local[0], it.y - home_local[1], -(it.z - home_local[2])
    return MissionItem("waypoint", north, east, alt,
                       acceptance_radius_m=it.param2 if it.param2 > 0 else None,
                       yaw_deg=it.param4 if math.isfinite(it.param4) else None)


@dataclass
class _Upload:
    count: int
    mission_type: int
    partner: tuple[int, int]
    items: list[Any] = field(default_factory=list)
    last_request_wall: float = 0.0
    retries: int = 0


_TO_INT_FRAME = {M.MAV_FRAME_GLOBAL: M.MAV_FRAME_GLOBAL_INT,
                 M.MAV_FRAME_GLOBAL_RELATIVE_ALT: M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                 M.MAV_FRAME_GLOBAL_TERRAIN_ALT: M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}
_TO_FLOAT_FRAME = {v: k for k, v in _TO_INT_FRAME.items()}


class MissionProtocol:
    """Mission and fence uploads / downloads (MISSION_* messages), as PX4 v1.16 runs them.

    PX4 starts in the legacy float mode: its first upload request is a MISSION_REQUEST; a
    client that answers MISSION_ACK UNSUPPORTED (MAVSDK) makes it switch to MISSION_REQUEST_INT
    and ask again, and any MISSION_ITEM_INT / MISSION_REQUEST_INT received switches it to the
    int mode too (recorded c; probed with MAVSDK's Geofence upload). Downloads give global
    items in the int frames (MAV_FRAME_GLOBAL_INT, GLOBAL_RELATIVE_ALT_INT) whatever frame
    they were uploaded in (probed: MAVSDK uploads fence vertices in MAV_FRAME_GLOBAL, PX4 gives
    them back in GLOBAL_INT), and PX4 says nothing on a geofence upload (no status text)."""

    def __init__(self, emulator: Px4Emulator) -> None:
        self._e = emulator
        self.items: list[Any] = []  # the uploaded mission (MISSION_ITEM_INT messages)
        self.fence_items: list[Any] = []  # the uploaded geofence (MISSION_ITEM_INT, FENCE)
        self._upload: _Upload | None = None
        self.int_mode = False  # PX4's _int_mode: false at boot

    def _ack(self, partner: tuple[int, int], result: int, mission_type: int) -> None:
        self._e.emit(M.MAVLink_mission_ack_message(partner[0], partner[1], result, mission_type))

    def _set_mission(self, items: list[Any]) -> None:
        e = self._e
        self.items = items
        e.autopilot.upload_mission(tuple(mission_item(it, e.home, e.home_local) for it in items))

    def on_mission_count(self, msg: Any) -> None:
        ap = self._e.autopilot
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.mission_type == M.MAV_MISSION_TYPE_FENCE:
            if msg.count == 0:
                self.fence_items = []
                self._ack(partner, M.MAV_MISSION_ACCEPTED, msg.mission_type)
                return
            self._upload = _Upload(msg.count, msg.mission_type, partner)  # item by item, as PX4
            self._request_next(time.monotonic())
            return
        if msg.mission_type != M.MAV_MISSION_TYPE_MISSION:
            self._ack(partner, M.MAV_MISSION_ACCEPTED, msg.mission_type)
            return
        if (ap.mode == FlightMode.MISSION and ap.armed
                and ap.landed_state != LandedState.ON_GROUND):
            self._ack(partner, M.MAV_MISSION_DENIED, msg.mission_type)
            return
        if msg.count == 0:
            self._set_mission([])
            self._ack(partner, M.MAV_MISSION_ACCEPTED, msg.mission_type)
            return
        self._upload = _Upload(msg.count, msg.mission_type, partner)
        self._request_next(time.monotonic())

    def _request_next(self, wall: float) -> None:
        up = self._upload
        assert up is not None
        up.last_request_wall = wall
        request = (M.MAVLink_mission_request_int_message if self.int_mode
                   else M.MAVLink_mission_request_message)
        self._e.emit(request(up.partner[0], up.partner[1], len(up.items), up.mission_type))

    def on_mission_ack(self, msg: Any) -> None:
        """During an upload: UNSUPPORTED means the other protocol mode (PX4 switches and asks
        again); OPERATION_CANCELLED ends the upload."""
        up = self._upload
        if up is None or msg.mission_type != up.mission_type:
            return
        if msg.type == M.MAV_MISSION_UNSUPPORTED:
            self.int_mode = not self.int_mode
            self._request_next(time.monotonic())
        elif msg.type == M.MAV_MISSION_OPERATION_CANCELLED:
            self._upload = None

    def on_mission_item(self, msg: Any) -> None:
        """A float-mode item (degrees): stored as its int-mode equivalent."""
        self.int_mode = False
        self._take_item(M.MAVLink_mission_item_int_message(
            msg.target_system, msg.target_component, msg.seq,
            _TO_INT_FRAME.get(msg.frame, msg.frame), msg.command, msg.current, msg.autocontinue,
            msg.param1, msg.param2, msg.param3, msg.param4,
            int(round(msg.x * 1e7)) if msg.frame in _TO_INT_FRAME else int(msg.x),
            int(round(msg.y * 1e7)) if msg.frame in _TO_INT_FRAME else int(msg.y),
            msg.z, msg.mission_type))

    def retry(self, wall: float) -> None:
        """Ask again for an item that did not come (PX4: every 250 ms, 8 times)."""
        up = self._upload
        if up is None or wall - up.last_request_wall < 0.25:
            return
        up.retries += 1
        if up.retries > 8:
            self._ack(up.partner, M.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
            self._upload = None
            return
        self._request_next(wall)

    def on_mission_item_int(self, msg: Any) -> None:
        self.int_mode = True
        self._take_item(msg)

    def _take_item(self, msg: Any) -> None:
        up = self._upload
        if up is None or msg.mission_type != up.mission_type:
            return
        if msg.seq != len(up.items):
            return  # duplicate or out of order: the retry timer asks again
        up.items.append(msg)
        up.retries = 0
        if len(up.items) < up.count:
            self._request_next(time.monotonic())
            return
        self._upload = None
        if up.mission_type == M.MAV_MISSION_TYPE_FENCE:
            ok = all(item.command in FENCE_COMMANDS for item in up.items)
            if ok:
                self.fence_items = list(up.items)
            self._ack(up.partner, M.MAV_MISSION_ACCEPTED if ok else M.MAV_MISSION_UNSUPPORTED,
                      M.MAV_MISSION_TYPE_FENCE)
            return
        if any(it.command not in NAV_COMMANDS and it.command not in MISSION_DO for it in up.items):
            self._ack(up.partner, M.MAV_MISSION_UNSUPPORTED, up.mission_type)
            return
        self._set_mission(list(up.items))
        self._ack(up.partner, M.MAV_MISSION_ACCEPTED, M.MAV_MISSION_TYPE_MISSION)
        self._e.send("MISSION_CURRENT")

    def on_mission_request_list(self, msg: Any) -> None:
        count = (len(self.items) if msg.mission_type == M.MAV_MISSION_TYPE_MISSION
                 else len(self.fence_items) if msg.mission_type == M.MAV_MISSION_TYPE_FENCE
                 else 0)
        self._e.emit(M.MAVLink_mission_count_message(msg.get_srcSystem(), msg.get_srcComponent(),
                                                     count, msg.mission_type))

    def on_mission_request_int(self, msg: Any) -> None:
        self.int_mode = True
        self._send_item(msg)

    def on_mission_request(self, msg: Any) -> None:
        self.int_mode = False
        self._send_item(msg)

    def _send_item(self, msg: Any) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.mission_type == M.MAV_MISSION_TYPE_FENCE and msg.seq < len(self.fence_items):
            it = self.fence_items[msg.seq]
            current = 0
        elif msg.mission_type != M.MAV_MISSION_TYPE_MISSION or msg.seq >= len(self.items):
            self._ack(src, M.MAV_MISSION_INVALID_SEQUENCE, msg.mission_type)
            return
        else:
            it = self.items[msg.seq]
            current = int(it.seq == self._e.autopilot.mission.current)
        frame = _TO_INT_FRAME.get(it.frame, it.frame)
        if self.int_mode:
            self._e.emit(M.MAVLink_mission_item_int_message(
                src[0], src[1], it.seq, frame, it.command, current, it.autocontinue, it.param1,
                it.param2, it.param3, it.param4, it.x, it.y, it.z, it.mission_type))
            return
        glob = frame in _TO_FLOAT_FRAME
        self._e.emit(M.MAVLink_mission_item_message(
            src[0], src[1], it.seq, _TO_FLOAT_FRAME.get(frame, frame), it.command, current,
            it.autocontinue, it.param1, it.param2, it.param3, it.param4,
            it.x / 1e7 if glob else float(it.x), it.y / 1e7 if glob else float(it.y), it.z,
            it.mission_type))

    def on_mission_clear_all(self, msg: Any) -> None:
        if msg.mission_type in (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_ALL):
            self._set_mission([])
        if msg.mission_type in (M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_ALL):
            self.fence_items = []  # MAVSDK's Geofence.clear_geofence (probed: then none)
        self._ack((msg.get_srcSystem(), msg.get_srcComponent()), M.MAV_MISSION_ACCEPTED,
                  msg.mission_type)

    def on_mission_set_current(self, msg: Any) -> None:
        if 0 <= msg.seq < len(self.items):
            self._e.autopilot.mission.set_current(msg.seq)
            self._e.send("MISSION_CURRENT")
