"""A MAVSDK client that flies PX4 flies the emulator the same way.

Each test drives the in-process emulator with an ordinary MAVSDK 4.1 client program (the
blocking API, plugins built on the system: :mod:`plain_mavsdk`) and asserts what PX4 v1.16 SITL
answered the same calls. PX4's answers were measured with

    PX4_INSTANCE=1 PX4_WAIT=1 start_px4.sh   # a fresh PX4 v1.16.0 SITL, SIH quad (sihsim_quadx)
    python benchmarks/probe_mavsdk_plugins.py --url udpin://0.0.0.0:14541 --tap --out px4.json

(the same probe against ``eaglemission sitl-vehicle`` gives the emulator's; reports/px4_emulator.md,
"MAVSDK plugins as PX4 answers them", has the table).
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable

import pytest
from eaglemission.drivers.vehicles import px4
from eaglemission.lab.vehicles.emulator.dialect import M
from plain_mavsdk import PlainClient, bearing_deg, plain_client

from eaglemission.types import FlightMode

pytestmark = pytest.mark.machine  # no port of its own (raw://): kept with the other
# real-time MAVSDK modules, a conservative choice (tests/conftest.py)

SPEEDUP = 6.0


def _stream(setter: Callable[[], object], seconds_emu: float) -> None:
    """Keep setting the setpoint at ~20 Hz, as a client does, for ``seconds_emu`` emulator s."""
    end = time.monotonic() + seconds_emu / SPEEDUP
    while time.monotonic() < end:
        setter()
        time.sleep(0.05)


def _offboard_setter(c: PlainClient, kind: str, ned: tuple[float, float, float], yaw0: float,
                     south_ll: tuple[float, float], hover: float) -> Callable[[], object]:
    """What a client calls (again and again) for one setpoint type, from where it is."""
    off = c.m["offboard"]
    o = c.offboard
    n0, e0, d0 = ned
    setters: dict[str, Callable[[], object]] = {
        "position_ned": lambda: o.set_position_ned(off.PositionNedYaw(n0 + 3, e0, d0, yaw0)),
        "velocity_ned": lambda: o.set_velocity_ned(off.VelocityNedYaw(0, 1, 0, yaw0)),
        "velocity_body": lambda: o.set_velocity_body(off.VelocityBodyYawspeed(1, 0, 0, 15)),
        "position_velocity_ned": lambda: o.set_position_velocity_ned(
            off.PositionNedYaw(n0 + 3, e0, d0, yaw0), off.VelocityNedYaw(0.5, 0, 0, yaw0)),
        "position_velocity_acceleration_ned": lambda: o.set_position_velocity_acceleration_ned(
            off.PositionNedYaw(n0, e0 + 3, d0, yaw0), off.VelocityNedYaw(0, 0.5, 0, yaw0),
            off.AccelerationNed(0, 0, 0)),
        "acceleration_ned": lambda: o.set_acceleration_ned(off.AccelerationNed(0.5, 0, 0)),
        "position_global": lambda: o.set_position_global(off.PositionGlobalYaw(
            south_ll[0], south_ll[1], -d0, yaw0, off.PositionGlobalYaw.AltitudeType.REL_HOME)),
        "attitude": lambda: o.set_attitude(off.Attitude(0, -5, yaw0, hover)),
        "attitude_rate": lambda: o.set_attitude_rate(off.AttitudeRate(0, 0, 10, hover)),
    }
    return setters[kind]


def test_offboard_every_setpoint_type_starts_and_flies() -> None:
    """PX4 v1.16 (probed, 3 fresh SITL runs): ``Offboard.start`` after each setpoint type is
    SUCCESS and the HEARTBEAT shows OFFBOARD; it flies them: body velocity 1 m/s forward with
    15 deg/s yaw speed turned 49-50 deg in 4 s; -5 deg pitch at hover thrust went 0.5-0.9 m
    forward in 2 s; a 10 deg/s yaw rate turned 15 deg in 2 s; 0.5 m/s^2 north moved 0.4-1.0 m in
    3 s; a global position 3 m south moved 3.0-3.8 m south."""
    with plain_client(SPEEDUP) as c:
        off = c.m["offboard"]
        hover = c.emu.param("MPC_THR_HOVER") if "MPC_THR_HOVER" in c.emu.params else 0.5
        c.take_off(8.0)
        for kind in ("position_ned", "velocity_ned", "velocity_body", "position_velocity_ned",
                     "position_velocity_acceleration_ned", "acceleration_ned", "position_global",
                     "attitude", "attitude_rate"):
            n0, e0, d0 = c.ned()
            yaw0 = c.yaw_deg()
            pos = c.telemetry.position()
            setter = _offboard_setter(c, kind, (n0, e0, d0), yaw0,
                                      (pos.latitude_deg - 3.0 / 111_132.0, pos.longitude_deg), hover)
            setter()
            assert c.offboard.start() == off.OffboardResult.SUCCESS, kind
            c.wait(lambda: c.mode() == FlightMode.OFFBOARD, 3.0, f"{kind}: OFFBOARD")
            _stream(setter, 3.0 if kind in ("attitude", "attitude_rate", "acceleration_ned") else 4.0)
            n, e, d = c.ned()
            dyaw = (c.yaw_deg() - yaw0 + 180.0) % 360.0 - 180.0
            moved = {"position_ned": n - n0 > 2.0, "velocity_ned": e - e0 > 2.0,
                     "velocity_body": dyaw > 30.0 and math.hypot(n - n0, e - e0) > 1.5,
                     "position_velocity_ned": n - n0 > 2.0,
                     "position_velocity_acceleration_ned": e - e0 > 2.0,
                     "acceleration_ned": n - n0 > 0.3,
                     "position_global": n0 - n > 2.0,
                     "attitude": math.hypot(n - n0, e - e0) > 0.3 and abs(d - d0) < 1.0,
                     "attitude_rate": dyaw > 10.0 and abs(d - d0) < 1.0}[kind]
            assert moved, (kind, (n - n0, e - e0, d - d0), dyaw)
            c.offboard.stop()
            c.wait(lambda: c.mode() == FlightMode.HOLD, 3.0, f"{kind}: HOLD after stop")
            assert not any("Offboard is currently not available" in x for x in _texts(c)), kind


def test_unsupported_offboard_frame_is_ignored_with_px4s_text() -> None:
    """PX4's MAVLink receiver takes SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED and
    MAV_FRAME_BODY_NED only; another frame is no offboard signal and is reported (STATUSTEXT
    CRITICAL "SET_POSITION_TARGET_LOCAL_NED coordinate frame N unsupported"; PX4 v1.16's
    receiver, not probed)."""
    with plain_client(SPEEDUP) as c:
        mav = M.MAVLink(None, srcSystem=245, srcComponent=190)
        c.emu.feed(M.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, M.MAV_FRAME_LOCAL_OFFSET_NED, 0b110111111000, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0
        ).pack(mav))
        c.wait(lambda: "SET_POSITION_TARGET_LOCAL_NED coordinate frame 7 unsupported" in _texts(c),
               2.0, "the unsupported-frame text")
        assert not c.emu.autopilot.offboard_signal()


def _mission_requests(c: PlainClient, since: float, mission_type: int) -> list[tuple[str, int]]:
    return [(t.msg.get_type(), t.msg.seq) for t in c.emu.traffic
            if t.wall_s >= since and t.direction == "out"
            and t.msg.get_type() in ("MISSION_REQUEST", "MISSION_REQUEST_INT")
            and t.msg.mission_type == mission_type]


def test_geofence_upload_item_by_item_like_px4() -> None:
    """MAVSDK's Geofence.upload_geofence (a 4-vertex inclusion polygon and a circle) on PX4
    v1.16 (probed): MISSION_COUNT 5 (mission_type FENCE), PX4 asks for item 0 with the legacy
    MISSION_REQUEST (its float mode at boot), MAVSDK answers MISSION_ACK UNSUPPORTED, PX4
    switches to MISSION_REQUEST_INT for items 0-4, MISSION_ACK ACCEPTED, no status text;
    MissionRaw.download_geofence gives the vertices back in MAV_FRAME_GLOBAL_INT (5), whatever
    frame they were uploaded in (MAVSDK: MAV_FRAME_GLOBAL); Geofence.clear_geofence is
    MISSION_CLEAR_ALL, ACCEPTED, and the download is then empty. The emulator asked with
    MISSION_REQUEST_INT from the start, gave frame 0 back and said "Geofence uploaded"."""
    with plain_client(SPEEDUP) as c:
        g = c.m["geofence"]
        lat, lon, d = 47.397742, 8.545594, 0.0009
        poly = g.Polygon([g.Point(lat - d, lon - d), g.Point(lat + d, lon - d),
                          g.Point(lat + d, lon + d), g.Point(lat - d, lon + d)], g.FenceType.INCLUSION)
        circle = g.Circle(g.Point(lat, lon), 150.0, g.FenceType.INCLUSION)
        t0 = time.monotonic()
        assert c.geofence.upload_geofence(g.GeofenceData([poly], [circle])) == g.GeofenceResult.SUCCESS
        fence = M.MAV_MISSION_TYPE_FENCE
        assert _mission_requests(c, t0, fence) == [("MISSION_REQUEST", 0)] + [
            ("MISSION_REQUEST_INT", i) for i in range(5)]
        assert [m.type for m in c.emu.received("MISSION_ACK")] == [M.MAV_MISSION_UNSUPPORTED]
        assert not [t for t in c.emu.sent("STATUSTEXT") if t.wall_s >= t0]
        items = c.mission_raw.download_geofence()
        assert [(i.command, i.frame, i.mission_type) for i in items] == (
            [(M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, M.MAV_FRAME_GLOBAL_INT, fence)] * 4
            + [(M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, M.MAV_FRAME_GLOBAL_INT, fence)])
        assert items[0].param1 == 4 and items[4].param1 == 150.0
        assert c.geofence.clear_geofence() == g.GeofenceResult.SUCCESS
        assert c.mission_raw.download_geofence() == []


def test_mission_upload_handshake_and_download_frames_like_px4() -> None:
    """MAVSDK's Mission.upload_mission (3 waypoints with speeds: 6 MAVLink items) right after
    boot on PX4 v1.16: MISSION_REQUEST 0 first (float mode), MISSION_ACK UNSUPPORTED from MAVSDK,
    then MISSION_REQUEST_INT 0-5 (recorded c; probed the same); MissionRaw.download_mission gives
    the waypoints in MAV_FRAME_GLOBAL_RELATIVE_ALT_INT (6) and the DO_CHANGE_SPEED items in
    MAV_FRAME_MISSION (2). The emulator asked MISSION_REQUEST_INT at once and gave frame 3 back."""
    with plain_client(SPEEDUP) as c:
        mi = c.m["mission"]
        pos = c.telemetry.position()

        def item(dn: float, de: float) -> object:
            return mi.MissionItem(latitude_deg=pos.latitude_deg + dn / 111_132.0,
                                  longitude_deg=pos.longitude_deg + de / 75_000.0,
                                  relative_altitude_m=10.0, speed_m_s=3.0, is_fly_through=True,
                                  gimbal_pitch_deg=math.nan, gimbal_yaw_deg=math.nan,
                                  camera_action=mi.MissionItem.CameraAction.NONE,
                                  loiter_time_s=math.nan, camera_photo_interval_s=math.nan,
                                  acceptance_radius_m=2.0, yaw_deg=math.nan,
                                  camera_photo_distance_m=math.nan,
                                  vehicle_action=mi.MissionItem.VehicleAction.NONE)

        t0 = time.monotonic()
        c.mission.upload_mission(mi.MissionPlan([item(10, 0), item(10, 10), item(0, 10)]))
        assert _mission_requests(c, t0, M.MAV_MISSION_TYPE_MISSION) == [("MISSION_REQUEST", 0)] + [
            ("MISSION_REQUEST_INT", i) for i in range(6)]
        raw = c.mission_raw.download_mission()
        assert [(i.command, i.frame) for i in raw] == [
            (M.MAV_CMD_NAV_WAYPOINT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT),
            (M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_FRAME_MISSION)] * 3
        plan = c.mission.download_mission()
        assert len(plan.mission_items) == 3 and plan.mission_items[1].speed_m_s == 3.0


def test_do_orbit_flies_a_circle_in_positions_orbit_sub_mode() -> None:
    """``Action.do_orbit(5 m, 2 m/s, HOLD_FRONT_TO_CIRCLE_CENTER, centre 5 m north, NaN)`` at
    8 m on PX4 v1.16 (probed, 3 runs): SUCCESS; HEARTBEAT custom mode main 3 (Position) sub 1
    (ORBIT), base_mode 0x91; MAVSDK reports POSCTL; half a circle (10.1-10.5 m north of the
    start) in 12 s at up to 1.72-1.75 m/s, the nose to the centre (yaw -174 to 178 deg), at the
    same altitude. Disarmed it is ACCEPTED too (Position/ORBIT, base_mode 0x11) and arming is then
    refused: TEMPORARILY_REJECTED, "Arming denied: Resolve system health failures first"."""
    with plain_client(SPEEDUP) as c:
        act = c.m["action"]
        c.take_off(8.0)
        n0, e0, d0 = c.ned()
        pos = c.telemetry.position()
        centre_ll = (pos.latitude_deg + 5.0 / 111_132.0, pos.longitude_deg)
        t0 = time.monotonic()
        assert c.action.do_orbit(5.0, 2.0, act.OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER,
                                 centre_ll[0], centre_ll[1], math.nan) == act.ActionResult.SUCCESS
        c.wait(lambda: c.mode() == FlightMode.POSCTL, 3.0, "Position (orbit)")
        centre = (n0 + 5.0, e0)
        b0 = bearing_deg(centre, c.ned())
        time.sleep(12.0 / SPEEDUP)
        n, e, d = c.ned()
        assert abs(math.dist((n, e), centre) - 5.0) < 1.0  # on the circle
        assert 7.0 < n - n0 < 11.0  # about half-way round, as PX4 (10.1-10.5 m)
        assert (bearing_deg(centre, (n, e, d)) - b0) % 360.0 < 270.0  # clockwise
        to_centre = math.degrees(math.atan2(centre[1] - e, centre[0] - n))
        assert abs((c.yaw_deg() - to_centre + 180.0) % 360.0 - 180.0) < 15.0
        assert abs(d - d0) < 0.5
        assert (3, 1, 0x91) in c.heartbeat_modes(t0)
        c.action.hold()
        c.action.land()
        c.wait(lambda: not c.armed(), 60.0, "landed and disarmed")
        t1 = time.monotonic()
        assert c.action.do_orbit(5.0, 2.0, act.OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER,
                                 centre_ll[0], centre_ll[1], math.nan) == act.ActionResult.SUCCESS
        c.wait(lambda: (3, 1, 0x11) in c.heartbeat_modes(t1), 3.0, "Position/ORBIT, disarmed")
        with pytest.raises(act.ActionError) as err:
            c.action.arm()
        assert err.value.result == act.ActionResult.COMMAND_DENIED
        assert "Arming denied: Resolve system health failures first" in _texts(c, t1)


def _gripper_acks(c: PlainClient, since: float, sysid: int = 246) -> list[tuple[int, int]]:
    return [(t.msg.result, t.msg.progress) for t in c.emu.sent("COMMAND_ACK")
            if t.wall_s >= since and t.msg.command == M.MAV_CMD_DO_GRIPPER
            and t.msg.target_system == sysid]


def test_gripper_answers_in_progress_then_accepted_like_px4() -> None:
    """DO_GRIPPER on PX4 v1.16 (probed on the wire, 3 runs): release from the grabbed state it
    boots in is IN_PROGRESS (progress 255), then ACCEPTED 1.04-1.10 s later (PD_GRIPPER_TO 1 s);
    release again: ACCEPTED at once; grab, then release at once: CANCELLED (to the grab's sender),
    IN_PROGRESS, ACCEPTED ~1.05 s later; grab twice at once: TEMPORARILY_REJECTED for the second.
    MAVSDK's MavlinkDirect.send_command waits through IN_PROGRESS for the final ACCEPTED. (MAVSDK's
    Gripper plugin returns UNKNOWN at the IN_PROGRESS and calls back again at the final ack,
    which crashes a client: the driver does not use it.)"""
    with plain_client(SPEEDUP) as c:
        mav = M.MAVLink(None, srcSystem=246, srcComponent=190)

        def gripper(action: int) -> None:
            c.emu.feed(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_GRIPPER, 0, 1, action,
                                                      0, 0, 0, 0, 0).pack(mav))

        IP, A = M.MAV_RESULT_IN_PROGRESS, M.MAV_RESULT_ACCEPTED
        t0 = time.monotonic()
        gripper(M.GRIPPER_ACTION_RELEASE)
        time.sleep(0.5 / SPEEDUP)
        assert _gripper_acks(c, t0) == [(IP, 255)]
        time.sleep(1.0 / SPEEDUP)
        assert _gripper_acks(c, t0) == [(IP, 255), (A, 0)]
        done = next(t.sim_s for t in c.emu.sent("COMMAND_ACK") if t.wall_s >= t0 and t.msg.result == A)
        start = next(t.sim_s for t in c.emu.sent("COMMAND_ACK") if t.wall_s >= t0)
        assert 0.95 < done - start < 1.15  # PD_GRIPPER_TO, emulator seconds
        t1 = time.monotonic()
        gripper(M.GRIPPER_ACTION_RELEASE)
        time.sleep(0.2 / SPEEDUP)
        assert _gripper_acks(c, t1) == [(A, 0)]
        t2 = time.monotonic()
        gripper(M.GRIPPER_ACTION_GRAB)
        gripper(M.GRIPPER_ACTION_RELEASE)
        time.sleep(1.5 / SPEEDUP)
        assert _gripper_acks(c, t2) == [(IP, 255), (6, 0), (IP, 255), (A, 0)]  # 6: CANCELLED
        t3 = time.monotonic()
        gripper(M.GRIPPER_ACTION_GRAB)
        gripper(M.GRIPPER_ACTION_GRAB)
        time.sleep(1.5 / SPEEDUP)
        assert _gripper_acks(c, t3) == [(IP, 255), (M.MAV_RESULT_TEMPORARILY_REJECTED, 0), (A, 0)]
        # MAVSDK's MavlinkDirect waits through IN_PROGRESS for the final ACCEPTED
        cmd = c.m["direct"].MavlinkMessage(
            message_name="COMMAND_LONG", system_id=0, component_id=0, target_system_id=1,
            target_component_id=1, fields_json=json.dumps(
                {"target_system": 1, "target_component": 1, "command": M.MAV_CMD_DO_GRIPPER,
                 "confirmation": 0, "param1": 1.0, "param2": 0.0, "param3": 0.0, "param4": 0.0,
                 "param5": 0.0, "param6": 0.0, "param7": 0.0}))
        t4 = time.monotonic()
        ack = c.direct.send_command(cmd)
        assert json.loads(ack.fields_json)["result"] == A
        assert time.monotonic() - t4 > 0.8 / SPEEDUP
        assert c.emu.snapshot().gripper == "release"


def test_reposition_right_after_takeoff_and_on_the_ground_is_accepted() -> None:
    """``Action.goto_location`` on PX4 v1.16 (probed, 4 runs): 0.2 s after ``takeoff()`` (still
    on the ground) SUCCESS, and it climbs and flies there (8 m north, 8 m up, in 15 s); disarmed,
    SUCCESS and Hold (nothing moves); armed on the ground, SUCCESS and it takes off to the target
    ("Takeoff detected" 0.5 s later). A DO_REPOSITION without param2's change-mode flag is
    UNSUPPORTED (PX4's Commander; MAVSDK always sets it)."""
    with plain_client(SPEEDUP) as c:
        pos = c.telemetry.position()
        amsl = pos.absolute_altitude_m - pos.relative_altitude_m
        lat8 = pos.latitude_deg + 8.0 / 111_132.0
        assert c.action.goto_location(lat8, pos.longitude_deg, amsl + 3.0, 0.0) is not None
        c.wait(lambda: c.mode() == FlightMode.HOLD, 2.0, "Hold")
        assert not c.armed() and -c.ned()[2] < 0.3
        c.action.set_takeoff_altitude(5.0)
        c.action.arm()
        c.action.takeoff()
        time.sleep(0.2 / SPEEDUP)
        c.action.goto_location(lat8, pos.longitude_deg, amsl + 8.0, 0.0)  # raises if refused
        n0 = c.ned()[0]
        c.wait(lambda: c.ned()[0] - n0 > 7.0 and -c.ned()[2] > 7.0, 30.0 / SPEEDUP * 2,
               "8 m north and 8 m up")
        c.action.land()
        c.wait(lambda: not c.armed(), 60.0, "landed and disarmed")
        c.action.arm()
        here = c.ned()
        c.action.goto_location(pos.latitude_deg + (here[0] + 3.0) / 111_132.0, pos.longitude_deg,
                               amsl + 3.0, 0.0)
        c.wait(lambda: -c.ned()[2] > 1.0, 10.0, "takes off to the target")
        mav = M.MAVLink(None, srcSystem=246, srcComponent=190)
        t0 = time.monotonic()
        c.emu.feed(M.MAVLink_command_int_message(1, 1, M.MAV_FRAME_GLOBAL, M.MAV_CMD_DO_REPOSITION,
                                                 0, 0, -1, 0, 0, math.nan, int(lat8 * 1e7),
                                                 int(pos.longitude_deg * 1e7), amsl + 3.0).pack(mav))
        c.wait(lambda: bool(_acks(c, t0, M.MAV_CMD_DO_REPOSITION)), 2.0, "DO_REPOSITION ack")
        assert _acks(c, t0, M.MAV_CMD_DO_REPOSITION) == [M.MAV_RESULT_UNSUPPORTED]


def _acks(c: PlainClient, since: float, command: int, sysid: int = 246) -> list[int]:
    return [t.msg.result for t in c.emu.sent("COMMAND_ACK")
            if t.wall_s >= since and t.msg.command == command and t.msg.target_system == sysid]


def _texts(c: PlainClient, since: float = 0.0) -> list[str]:
    """The STATUSTEXTs the emulator sent since then, 50-character chunks joined (by id)."""
    out: list[str] = []
    last_id = None
    for t in c.emu.sent("STATUSTEXT"):
        if t.wall_s < since:
            continue
        chunk = _text(t.msg.text)
        if t.msg.id and t.msg.id == last_id and t.msg.chunk_seq > 0:
            out[-1] += chunk
        else:
            out.append(chunk)
        last_id = t.msg.id
    return out


def _text(raw: object) -> str:
    """A string field of a message the emulator built (bytes) or parsed (str)."""
    s = raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)
    return s.split("\x00", 1)[0].strip()


def test_land_return_and_takeoff_while_disarmed_are_selected_like_px4() -> None:
    """Disarmed on the ground, PX4 v1.16 (probed): ``Action.land()`` SUCCESS, Land, "Landing
    at current position"; ``return_to_launch()`` SUCCESS, Return, no status text;
    ``takeoff()`` SUCCESS, Takeoff, no status text; nothing moves."""
    with plain_client(SPEEDUP) as c:
        t0 = time.monotonic()
        for call, mode in ((c.action.land, FlightMode.LAND),
                           (c.action.return_to_launch, FlightMode.RETURN_TO_LAUNCH),
                           (c.action.takeoff, FlightMode.TAKEOFF), (c.action.hold, FlightMode.HOLD)):
            call()  # raises ActionError if refused
            c.wait(lambda mode=mode: c.mode() == mode, 3.0, mode.value)
            assert not c.armed() and -c.ned()[2] < 0.3
        assert _texts(c, t0) == ["Landing at current position"]


def test_parameters_are_px4_v1_16s_sih_quad_set() -> None:
    """``Param.get_all_params`` on PX4 v1.16 SIH (probed): 904 parameters (281 int, 623 float),
    after PX4's _HASH_CHECK (UINT32, index 65535), with the airframe's values (RTL_RETURN_ALT 30,
    COM_LOW_BAT_ACT 3, MPC_THR_HOVER 0.5, COM_DL_LOSS_T an INT32, no COM_POS_FS_DELAY);
    MAV_SYS_ID is the autopilot's system id."""
    with plain_client(SPEEDUP) as c:
        t0 = time.monotonic()
        allp = c.param.get_all_params()
        ints = {p.name: p.value for p in allp.int_params}
        floats = {p.name: p.value for p in allp.float_params}
        assert (len(ints), len(floats)) == (281, 623)
        assert floats["RTL_RETURN_ALT"] == 30.0 and floats["MPC_THR_HOVER"] == 0.5
        assert ints["COM_LOW_BAT_ACT"] == 3 and ints["COM_DL_LOSS_T"] == 10
        assert ints["MAV_SYS_ID"] == 1 and ints["SYS_AUTOSTART"] == 10040
        assert "COM_POS_FS_DELAY" not in ints and "COM_POS_FS_DELAY" not in floats
        values = [t.msg for t in c.emu.sent("PARAM_VALUE") if t.wall_s >= t0]
        assert _text(values[0].param_id) == "_HASH_CHECK"
        assert values[0].param_type == M.MAV_PARAM_TYPE_UINT32 and values[0].param_index == 65535
        assert {m.param_count for m in values} == {904}
        names = [_text(m.param_id) for m in values[1:]]
        assert names == list(px4.default_params()) and names[:3] == ["ASPD_SCALE_1", "ATT_EN", "BAT1_CAPACITY"]


def test_parameter_of_another_type_or_unknown_name_is_not_answered_like_px4() -> None:
    """PARAM_SET of a float parameter as INT32 (``Param.set_param_int("MPC_XY_CRUISE", 4)``):
    PX4 v1.16 ignores it (console "param types mismatch") and keeps the value; MAVSDK retries
    6 times over 3 s and returns TIMEOUT (or WRONG_TYPE when a late PARAM_VALUE of the name
    arrives meanwhile; probed both). An unknown name is not answered either (probed: TIMEOUT
    after 3.0 s for get and set, int and float). PX4 answers a good PARAM_SET twice, the second
    11 ms later (recorded a)."""
    with plain_client(SPEEDUP) as c:
        pm = c.m["param"]
        with pytest.raises(pm.ParamError) as err:
            c.param.set_param_int("MPC_XY_CRUISE", 4)
        assert err.value.result in (pm.ParamResult.TIMEOUT, pm.ParamResult.WRONG_TYPE)
        assert c.emu.param("MPC_XY_CRUISE") == 5.0
        assert not [m for m in c.emu.sent("PARAM_VALUE") if _text(m.msg.param_id) == "MPC_XY_CRUISE"]
        with pytest.raises(pm.ParamError) as err:
            c.param.get_param_float("EAGLE_NO_SUCH")
        assert err.value.result == pm.ParamResult.TIMEOUT
        t0 = time.monotonic()
        c.param.set_param_float("MPC_XY_CRUISE", 4.0)
        c.wait(lambda: len([m for m in c.emu.sent("PARAM_VALUE") if m.wall_s >= t0]) == 2, 2.0,
               "two PARAM_VALUE")
        first, second = [m for m in c.emu.sent("PARAM_VALUE") if m.wall_s >= t0]
        assert 0.008 < second.wall_s - first.wall_s < 0.1


def test_telemetry_streams_px4_sends() -> None:
    """MAVSDK's Telemetry imu (HIGHRES_IMU), odometry (ODOMETRY), altitude (ALTITUDE),
    fixedwing_metrics (VFR_HUD), scaled_pressure and unix_epoch_time (SYSTEM_TIME) on PX4 v1.16
    SIH (probed over 4 s, Onboard link): 49.5, 29.5, 9.8, 9.8, 0.8-1.0 and 0.8-1.0 Hz. The
    emulator sent none of them."""
    with plain_client(SPEEDUP) as c:
        t = c.telemetry
        counts = {"imu": 0, "odometry": 0, "altitude": 0, "fixedwing_metrics": 0,
                  "scaled_pressure": 0, "unix_epoch_time": 0}
        handles = []
        for name in counts:
            def cb(_data: object, _ud: object = None, name: str = name) -> None:
                counts[name] += 1
            handles.append((name, getattr(t, f"subscribe_{name}")(cb)))
        time.sleep(3.0)
        for name, h in handles:
            getattr(t, f"unsubscribe_{name}")(h)
        rates = {k: v / 3.0 for k, v in counts.items()}
        expected = {"imu": 50.0, "odometry": 30.0, "altitude": 10.0, "fixedwing_metrics": 10.0,
                    "scaled_pressure": 1.0, "unix_epoch_time": 1.0}
        for k, hz in expected.items():
            assert 0.6 * hz <= rates[k] <= 1.4 * hz + 0.4, (k, rates[k])
        imu = t.imu()
        assert abs(imu.acceleration_frd.down_m_s2 + 9.8) < 0.3  # on the ground, level
        assert abs(t.altitude().altitude_relative_m) < 0.5


def test_manual_control_deflection_is_acceleration_based_like_px4() -> None:
    """ManualControl on PX4 v1.16 (probed, 3 runs at 10 m): ``start_position_control`` 3 ms
    after the first ``set_manual_control_input`` is refused (ACCEPTED then TEMPORARILY_REJECTED);
    with the sticks streaming, x = 0.5 for 3 s flies 1.5-2.3 m forward at up to 1.2 m/s (PX4's
    acceleration-based Position mode, MPC_XY_MAN_EXPO 0.6). The emulator took the first message
    as input and flew the stick as a velocity: 9.1 m at 5 m/s."""
    with plain_client(SPEEDUP) as c:
        c.take_off(8.0)
        c.manual.set_manual_control_input(0.0, 0.0, 0.5, 0.0)
        t0 = time.monotonic()
        c.manual.start_position_control()  # MAVSDK returns on the first ack (ACCEPTED)
        c.wait(lambda: len(_acks(c, t0, M.MAV_CMD_DO_SET_MODE, 245)) == 2, 2.0, "two acks")
        assert _acks(c, t0, M.MAV_CMD_DO_SET_MODE, 245) == [
            M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_TEMPORARILY_REJECTED]
        time.sleep(1.5 / SPEEDUP)
        assert c.mode() == FlightMode.HOLD
        sticks = [0.0, 0.0, 0.5, 0.0]
        stop = threading.Event()

        def stream() -> None:
            while not stop.wait(0.05):
                c.manual.set_manual_control_input(*sticks)

        th = threading.Thread(target=stream, daemon=True)
        th.start()
        try:
            time.sleep(0.3)
            c.manual.start_position_control()
            c.wait(lambda: c.mode() == FlightMode.POSCTL, 3.0, "Position")
            n0, e0, _ = c.ned()
            speeds = []
            sticks[0] = 0.5
            end = time.monotonic() + 3.0 / SPEEDUP
            while time.monotonic() < end:
                v = c.telemetry.velocity_ned()
                speeds.append(math.hypot(v.north_m_s, v.east_m_s))
                time.sleep(0.02)
            n, e, _ = c.ned()
            assert 0.8 < math.hypot(n - n0, e - e0) < 4.0
            assert max(speeds) < 2.5
            sticks[0] = 0.0
        finally:
            stop.set()
            th.join(2.0)
