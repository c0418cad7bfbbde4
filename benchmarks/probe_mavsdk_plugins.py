"""Probe what an ordinary MAVSDK 4.1 client gets from an autopilot, plugin by plugin: PX4 v1.16
SITL or the PX4-like emulator, so the two can be compared (a MAVSDK client that flies PX4
must fly the emulator the same way: tests/drivers/vehicles/test_px4_probed_mavsdk.py).

    # a fresh PX4 SITL (SIH) whose API link sends to 14541 (instance 1)
    python benchmarks/probe_mavsdk_plugins.py --url udpin://0.0.0.0:14541 --tap --out px4.json
    # the emulator, as its own process
    eaglemission sitl-vehicle --mavlink udpout://127.0.0.1:14600 &
    python benchmarks/probe_mavsdk_plugins.py --url udpin://0.0.0.0:14600 --tap --out emu.json
    # the differences
    python benchmarks/probe_mavsdk_plugins.py --compare px4.json emu.json

Only plain MAVSDK calls (``mavsdk.asyncio``: Action, Offboard with every setpoint type but
actuator control, Mission, MissionRaw, Geofence, Param, ManualControl, Gripper, Telemetry),
each bounded by a timeout. What each call answered (result code, duration) is recorded with
what followed: the flight modes telemetry showed, the motion (local NED), the status texts.
With ``--tap`` a loopback UDP relay between the autopilot and MAVSDK also records the MAVLink
on the wire (COMMAND_ACK sequences such as IN_PROGRESS, the mission / fence items requested one
by one, PARAM_VALUE answers, the setpoint messages MAVSDK sent); the relay takes the URL's port
and MAVSDK listens on a free one.

The flight: arm, takeoff with a reposition 0.2 s after it, the gripper, an orbit, each offboard
setpoint type for a few seconds at ~10 m (each started from Hold with MAVSDK's
``Offboard.start``), ManualControl's Position mode, a mission started in the air, RTL (its
first seconds), land. Start a fresh autopilot for every run. Not sent: actuator-control
offboard (zero actuator outputs would drop the vehicle), reboot, kill, terminate.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import select
import socket
import statistics
import sys
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

UNKNOWN_PARAM = "EAGLE_NO_SUCH"
STREAMS = ("position", "home", "in_air", "landed_state", "armed", "vtol_state",
           "attitude_quaternion", "attitude_euler", "attitude_angular_velocity_body",
           "velocity_ned", "gps_info", "raw_gps", "battery", "flight_mode", "health",
           "rc_status", "status_text", "actuator_control_target", "actuator_output_status",
           "odometry", "position_velocity_ned", "ground_truth", "fixedwing_metrics", "imu",
           "scaled_imu", "raw_imu", "health_all_ok", "unix_epoch_time", "distance_sensor",
           "scaled_pressure", "heading", "altitude", "wind")


# ------------------------------------------------------------------------------------------------
# the wire tap
# ------------------------------------------------------------------------------------------------
class Tap:
    """A loopback UDP relay: ``port`` (where the autopilot sends) <-> MAVSDK on ``client_port``;
    every message decoded and kept as (monotonic time, 'down' | 'up', message)."""

    def __init__(self, port: int) -> None:
        from pymavlink.dialects.v20 import development as mav

        self.M = mav
        self._down_parser = mav.MAVLink(None)
        self._up_parser = mav.MAVLink(None)
        self._mav = mav.MAVLink(None, srcSystem=246, srcComponent=190)
        self._up_parser2 = mav.MAVLink(None)
        for p in (self._down_parser, self._up_parser, self._up_parser2):
            p.robust_parsing = True
        self.ap_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.ap_side.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.ap_side.bind(("0.0.0.0", port))
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.bind(("127.0.0.1", 0))
        self.client_port = probe.getsockname()[1]
        probe.close()
        self.client_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.client_side.bind(("127.0.0.1", 0))
        self._ap_addr: tuple[str, int] | None = None
        self.ap_sysid = 0
        self.log: list[tuple[float, str, Any]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        socks = [self.ap_side, self.client_side]
        while not self._stop.is_set():
            ready, _, _ = select.select(socks, [], [], 0.1)
            for s in ready:
                try:
                    data, addr = s.recvfrom(65535)
                except OSError:
                    continue
                now = time.monotonic()
                if s is self.ap_side:
                    self._ap_addr = addr
                    self.client_side.sendto(data, ("127.0.0.1", self.client_port))
                    self._keep(now, "down", self._down_parser, data)
                elif self._ap_addr is not None:
                    self.ap_side.sendto(data, self._ap_addr)
                    self._keep(now, "up", self._up_parser, data)

    def _keep(self, now: float, direction: str, parser: Any, data: bytes) -> None:
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception:  # a bad packet is recorded as nothing
            return
        for m in msgs:
            if m.get_type() != "BAD_DATA":
                self.log.append((now, direction, m))
                if direction == "down" and m.get_type() == "HEARTBEAT" and self.ap_sysid == 0:
                    self.ap_sysid = m.get_srcSystem()

    def inject(self, msg: Any) -> None:
        """Send ``msg`` to the autopilot as a second ground station (sysid 246)."""
        if self._ap_addr is not None:
            data = msg.pack(self._mav)
            self._mav.seq = (self._mav.seq + 1) % 256
            self.ap_side.sendto(data, self._ap_addr)
            self._keep(time.monotonic(), "up", self._up_parser2, data)

    def window(self, t0: float, t1: float) -> list[tuple[float, str, Any]]:
        return [x for x in list(self.log) if t0 <= x[0] <= t1]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.ap_side.close()
        self.client_side.close()


def wire_summary(tap: Tap | None, t0: float, t1: float) -> dict[str, Any]:
    """What crossed the link in [t0, t1]: acks, status texts, the client's message types, the
    mission / param protocol."""
    if tap is None:
        return {}
    M = tap.M
    out: dict[str, Any] = {"acks": [], "statustext": [], "up": {}, "down_proto": [],
                           "setpoints": [], "heartbeat_modes": []}
    cmd_sent: dict[int, float] = {}
    for t, d, m in tap.window(t0, t1):
        k = m.get_type()
        if d == "up":
            out["up"][k] = out["up"].get(k, 0) + 1
            if k in ("COMMAND_LONG", "COMMAND_INT"):
                cmd_sent.setdefault(m.command, t)
            if k in ("SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT",
                     "SET_ATTITUDE_TARGET") and len(out["setpoints"]) < 1:
                out["setpoints"].append({"type": k, "frame": getattr(m, "coordinate_frame", None),
                                         "type_mask": m.type_mask})
            if k in ("PARAM_SET", "PARAM_REQUEST_READ", "MISSION_COUNT", "MISSION_ITEM_INT",
                     "MISSION_REQUEST_LIST", "MISSION_REQUEST_INT", "MISSION_CLEAR_ALL",
                     "MISSION_ACK"):
                out["down_proto"].append(("up", round(t - t0, 3), _short(m)))
        else:
            if k == "COMMAND_ACK":
                sent = cmd_sent.get(m.command)
                out["acks"].append({"command": _enum(M.enums["MAV_CMD"], m.command),
                                    "result": _enum(M.enums["MAV_RESULT"], m.result),
                                    "progress": m.progress,
                                    "after_s": None if sent is None else round(t - sent, 3)})
            elif k == "HEARTBEAT" and m.get_srcComponent() == 1:
                hm = f"main={(m.custom_mode >> 16) & 0xFF} sub={(m.custom_mode >> 24) & 0xFF} base=0x{m.base_mode:02x}"
                if not out["heartbeat_modes"] or out["heartbeat_modes"][-1] != hm:
                    out["heartbeat_modes"].append(hm)
            elif k == "STATUSTEXT":
                out["statustext"].append((round(t - t0, 3), str(m.text).strip()))
            elif k in ("PARAM_VALUE", "PARAM_ERROR", "MISSION_REQUEST_INT", "MISSION_REQUEST",
                       "MISSION_ACK", "MISSION_COUNT", "MISSION_ITEM_INT"):
                out["down_proto"].append(("down", round(t - t0, 3), _short(m)))
    if len(out["down_proto"]) > 40:
        n = len(out["down_proto"])
        out["down_proto"] = out["down_proto"][:20] + [f"... {n - 40} more ..."] + out["down_proto"][-20:]
    return out


def _enum(table: dict[int, Any], value: int) -> str:
    e = table.get(value)
    return e.name.replace("MAV_CMD_", "").replace("MAV_RESULT_", "") if e is not None else str(value)


def _short(m: Any) -> str:
    k = m.get_type()
    if k in ("PARAM_VALUE", "PARAM_SET", "PARAM_REQUEST_READ"):
        pid = m.param_id if isinstance(m.param_id, str) else m.param_id.decode(errors="ignore")
        extra = f" idx={m.param_index} count={m.param_count}" if k == "PARAM_VALUE" else ""
        return f"{k} {pid.rstrip(chr(0))} type={getattr(m, 'param_type', '-')}{extra}"
    if k == "PARAM_ERROR":
        return f"{k} {m.param_id} idx={m.param_index} error={m.error}"
    if k in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ITEM_INT"):
        cmd = f" cmd={m.command}" if k == "MISSION_ITEM_INT" else ""
        return f"{k} seq={m.seq} type={m.mission_type}{cmd}"
    if k in ("MISSION_COUNT",):
        return f"{k} count={m.count} type={m.mission_type}"
    if k == "MISSION_ACK":
        return f"{k} result={m.type} type={m.mission_type}"
    if k in ("MISSION_REQUEST_LIST", "MISSION_CLEAR_ALL"):
        return f"{k} type={m.mission_type}"
    return k


# ------------------------------------------------------------------------------------------------
# telemetry recorder
# ------------------------------------------------------------------------------------------------
class Recorder:
    """One task per stream the flight steps are judged on (local NED, attitude, mode, armed,
    in air, status texts), each sample stamped on receipt."""

    def __init__(self, tel: Any) -> None:
        self.tel = tel
        self.ned: list[tuple[float, float, float, float, float, float, float]] = []
        self.att: list[tuple[float, float, float, float]] = []
        self.mode: list[tuple[float, str]] = []
        self.armed: list[tuple[float, bool]] = []
        self.in_air: list[tuple[float, bool]] = []
        self.texts: list[tuple[float, str]] = []
        self.gps: list[tuple[float, float, float, float]] = []
        self._tasks: list[asyncio.Task[None]] = []

    def start(self) -> None:
        async def pump(gen: Any, fn: Callable[[float, Any], None]) -> None:
            async for x in gen:
                fn(time.monotonic(), x)

        t = self.tel
        specs = [
            (t.subscribe_position_velocity_ned(), lambda ts, x: self.ned.append(
                (ts, x.position.north_m, x.position.east_m, x.position.down_m,
                 x.velocity.north_m_s, x.velocity.east_m_s, x.velocity.down_m_s))),
            (t.subscribe_attitude_euler(), lambda ts, x: self.att.append(
                (ts, x.roll_deg, x.pitch_deg, x.yaw_deg))),
            (t.subscribe_flight_mode(), lambda ts, x: self._change(self.mode, ts, x.name)),
            (t.subscribe_armed(), lambda ts, x: self._change(self.armed, ts, bool(x))),
            (t.subscribe_in_air(), lambda ts, x: self._change(self.in_air, ts, bool(x))),
            (t.subscribe_status_text(), lambda ts, x: self.texts.append((ts, x.text))),
            (t.subscribe_position(), lambda ts, x: self.gps.append(
                (ts, x.latitude_deg, x.longitude_deg, x.relative_altitude_m))),
        ]
        self._tasks = [asyncio.create_task(pump(g, f)) for g, f in specs]

    @staticmethod
    def _change(lst: list[Any], ts: float, v: Any) -> None:
        if not lst or lst[-1][1] != v:
            lst.append((ts, v))

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(BaseException):
                await task

    def latest(self) -> dict[str, Any]:
        n = self.ned[-1] if self.ned else (0.0,) + (math.nan,) * 6
        a = self.att[-1] if self.att else (0.0, math.nan, math.nan, math.nan)
        g = self.gps[-1] if self.gps else (0.0, math.nan, math.nan, math.nan)
        return {"ned": n[1:4], "vel": n[4:7], "yaw": a[3], "lat": g[1], "lon": g[2], "rel_alt": g[3],
                "mode": self.mode[-1][1] if self.mode else "?",
                "armed": self.armed[-1][1] if self.armed else None,
                "in_air": self.in_air[-1][1] if self.in_air else None}

    def summary(self, t0: float, t1: float) -> dict[str, Any]:
        """Motion and modes in [t0, t1]."""
        ned = [x for x in self.ned if t0 <= x[0] <= t1]
        att = [x for x in self.att if t0 <= x[0] <= t1]
        modes = [m for ts, m in self.mode if t0 <= ts <= t1]
        before = [m for ts, m in self.mode if ts < t0]
        out: dict[str, Any] = {
            "modes": ([before[-1]] if before else []) + modes,
            "mode_changes": [(round(ts - t0, 2), m) for ts, m in self.mode if t0 <= ts <= t1],
            "armed_changes": [(round(ts - t0, 2), v) for ts, v in self.armed if t0 <= ts <= t1],
            "texts": [(round(ts - t0, 2), s) for ts, s in self.texts if t0 <= ts <= t1]}
        if len(ned) >= 2:
            a, b = ned[0], ned[-1]
            speeds = [math.hypot(x[4], x[5]) for x in ned]
            out.update(
                displacement_ned_m=[round(b[i] - a[i], 2) for i in (1, 2, 3)],
                start_ned_m=[round(a[i], 2) for i in (1, 2, 3)],
                height_min_max_m=[round(-max(x[3] for x in ned), 2), round(-min(x[3] for x in ned), 2)],
                max_ground_speed_mps=round(max(speeds), 2),
                mean_velocity_ned_mps=[round(statistics.fmean(x[i] for x in ned), 2) for i in (4, 5, 6)])
        if len(att) >= 2:
            dyaw = (att[-1][3] - att[0][3] + 180.0) % 360.0 - 180.0
            out.update(yaw_change_deg=round(dyaw, 1),
                       pitch_min_max_deg=[round(min(x[2] for x in att), 1), round(max(x[2] for x in att), 1)],
                       roll_min_max_deg=[round(min(x[1] for x in att), 1), round(max(x[1] for x in att), 1)])
        return out


# ------------------------------------------------------------------------------------------------
# the probe
# ------------------------------------------------------------------------------------------------
def result_name(exc: BaseException) -> str:
    r = getattr(exc, "result", None)
    if r is not None:
        return str(getattr(r, "name", r))
    if isinstance(exc, TimeoutError):
        return "PROBE_TIMEOUT"
    return f"{type(exc).__name__}: {exc}"


class Probe:
    def __init__(self, url: str, tap: Tap | None) -> None:
        self.url = url
        self.tap = tap
        self.out: dict[str, Any] = {"url": url, "steps": {}}
        self.rec: Recorder | None = None
        self.out_path: str | None = None

    def dump(self, path: str | None) -> None:
        """Write the findings so far (after every step: a crash keeps them)."""
        if path:
            with open(path, "w", encoding="utf-8") as f:
                json.dump(self.out, f, indent=1, default=str)

    def log(self, s: str) -> None:
        print(s, flush=True)

    async def call(self, name: str, fn: Callable[[], Awaitable[Any]], timeout_s: float = 10.0,
                   watch_s: float = 0.0, keep: Callable[[Any], Any] | None = None) -> Any:
        """Run one MAVSDK call, bounded; record its result and duration, then what followed
        for ``watch_s`` (modes, motion, status texts, the wire)."""
        t0 = time.monotonic()
        value: Any = None
        try:
            value = await asyncio.wait_for(fn(), timeout_s)
            result = "SUCCESS"
        except Exception as exc:  # the result is what we record
            result = result_name(exc)
        dt = time.monotonic() - t0
        if watch_s > 0:
            await asyncio.sleep(watch_s)
        t1 = time.monotonic()
        step: dict[str, Any] = {"result": result, "call_s": round(dt, 3)}
        if value is not None:
            step["value"] = keep(value) if keep is not None else _plain(value)
        if self.rec is not None and watch_s > 0:
            step.update(self.rec.summary(t0, t1))
        step["wire"] = wire_summary(self.tap, t0, t1)
        self.out["steps"][name] = step
        self.dump(self.out_path)
        self.log(f"{name:32s} {result:24s} {dt:6.2f} s  " + _brief(step))
        return value

    def note(self, name: str, **kw: Any) -> None:
        self.out["steps"][name] = kw
        self.dump(self.out_path)
        self.log(f"{name:32s} {kw}")


def _plain(v: Any) -> Any:
    if isinstance(v, (int, float, str, bool)) or v is None:
        return v.name if hasattr(v, "name") else v
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v[:20]]
    return str(v)[:300]


def _brief(step: dict[str, Any]) -> str:
    parts = []
    if "modes" in step:
        parts.append("modes=" + ">".join(step["modes"]))
    if "displacement_ned_m" in step:
        parts.append(f"d={step['displacement_ned_m']}")
    acks = step.get("wire", {}).get("acks")
    if acks:
        parts.append("acks=" + ",".join(f"{a['command']}:{a['result']}@{a['after_s']}" for a in acks[:4]))
    return " ".join(parts)


async def wait_until(pred: Callable[[], bool], timeout_s: float, what: str) -> bool:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            print(f"  (not reached within {timeout_s:g} s: {what})", flush=True)
            return False
        await asyncio.sleep(0.05)
    return True


async def run_probe(url: str, use_tap: bool, connect_timeout_s: float,
                    out_path: str | None) -> dict[str, Any]:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync, OrbitYawBehavior
    from mavsdk.asyncio.plugins.geofence import (
        Circle,
        FenceType,
        GeofenceAsync,
        GeofenceData,
        Point,
        Polygon,
    )
    from mavsdk.asyncio.plugins.gripper import GripperAsync
    from mavsdk.asyncio.plugins.info import InfoAsync
    from mavsdk.asyncio.plugins.manual_control import ManualControlAsync
    from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
    from mavsdk.asyncio.plugins.offboard import (
        AccelerationNed,
        Attitude,
        AttitudeRate,
        OffboardAsync,
        PositionGlobalYaw,
        PositionNedYaw,
        VelocityBodyYawspeed,
        VelocityNedYaw,
    )
    from mavsdk.asyncio.plugins.param import ParamAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    port = int(url.rsplit(":", 1)[1])
    tap = Tap(port) if use_tap else None
    client_url = f"udpin://127.0.0.1:{tap.client_port}" if tap is not None else url
    probe = Probe(url, tap)
    probe.out_path = out_path
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    plugins: list[Any] = []
    try:
        t0 = time.monotonic()
        await asyncio.wait_for(sdk.add_any_connection(client_url), 10.0)
        system = await sdk.first_autopilot(timeout_s=connect_timeout_s)
        if system is None:
            raise SystemExit(f"no autopilot heard on {url} within {connect_timeout_s:g} s")
        sysid = await system.get_system_id()
        probe.note("connect", discover_s=round(time.monotonic() - t0, 2), system_id=sysid)
        tel, act, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        mis, raw, geo = MissionAsync(system), MissionRawAsync(system), GeofenceAsync(system)
        par, man, grip, info = (ParamAsync(system), ManualControlAsync(system),
                                GripperAsync(system), InfoAsync(system))
        plugins = [tel, act, off, mis, raw, geo, par, man, grip, info]
        rec = probe.rec = Recorder(tel)
        rec.start()
        ok = await wait_until(lambda: bool(rec.gps) and bool(rec.mode), 20.0, "telemetry")
        health_ok = False
        async for h in tel.subscribe_health():
            if h.is_global_position_ok and h.is_home_position_ok and h.is_armable:
                health_ok = True
                break
            if time.monotonic() - t0 > 40.0:
                break
        probe.note("health", telemetry=ok, health_ok=health_ok, after_s=round(time.monotonic() - t0, 2))
        await probe.call("info.get_version", info.get_version, keep=lambda v: str(v)[:200])

        await telemetry_rates(probe, tel)
        await params(probe, par)
        await geofence(probe, geo, raw, Circle, FenceType, GeofenceData, Point, Polygon)
        home = rec.latest()
        lat0, lon0 = home["lat"], home["lon"]
        m_per_deg_lat = 111_132.0
        m_per_deg_lon = 111_320.0 * math.cos(math.radians(lat0))

        def geo_of(n: float, e: float) -> tuple[float, float]:
            return lat0 + n / m_per_deg_lat, lon0 + e / m_per_deg_lon

        await mission_upload(probe, mis, raw, MissionItem, MissionPlan, geo_of)

        # --------------------------------------------------------------- flight: action
        await probe.call("action.set_takeoff_altitude(5)", lambda: act.set_takeoff_altitude(5.0))
        await probe.call("action.get_takeoff_altitude", act.get_takeoff_altitude)
        await probe.call("action.get_return_to_launch_altitude", act.get_return_to_launch_altitude)
        home_amsl = await _amsl(tel)
        probe.note("home_amsl", value=home_amsl)
        tl = geo_of(3.0, 0.0)
        await probe.call("action.goto_location(disarmed)",
                         lambda: act.goto_location(tl[0], tl[1], home_amsl + 3.0, 0.0), watch_s=2.0)
        await probe.call("action.arm", act.arm, watch_s=1.5)
        await probe.call("action.takeoff", act.takeoff)
        await asyncio.sleep(0.2)
        tl = geo_of(8.0, 0.0)
        await probe.call("action.goto_location(0.2s after takeoff)",
                         lambda: act.goto_location(tl[0], tl[1], home_amsl + 8.0, 0.0), watch_s=15.0)
        await wait_until(lambda: rec.latest()["rel_alt"] > 7.0, 40.0, "8 m")
        await asyncio.sleep(3.0)
        await probe.call("action.set_current_speed(3)", lambda: act.set_current_speed(3.0))
        here = rec.latest()
        c = geo_of(here["ned"][0] + 5.0, here["ned"][1])
        await probe.call("action.do_orbit(r5,v2)", lambda: act.do_orbit(
            5.0, 2.0, OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER, c[0], c[1], math.nan),
            watch_s=12.0)
        await probe.call("action.hold(after orbit)", act.hold, watch_s=4.0)

        # --------------------------------------------------------------- flight: offboard
        hover = await _hover_thrust(par)
        await offboard_all(probe, off, act, rec, hover, geo_of, home_amsl, PositionNedYaw,
                           VelocityNedYaw, VelocityBodyYawspeed, AccelerationNed, Attitude,
                           AttitudeRate, PositionGlobalYaw)

        # --------------------------------------------------------------- flight: mission
        await probe.call("mission.start_mission(in air)", mis.start_mission, watch_s=15.0)
        prog = await _maybe(mis.mission_progress)
        probe.note("mission.progress after 15 s", value=str(prog))
        await probe.call("action.hold(after mission)", act.hold, watch_s=3.0)
        await probe.call("mission.clear_mission", mis.clear_mission)

        # --------------------------------------------------------------- flight: manual control
        await manual_control(probe, man, act)
        await probe.call("hold 6 s after MANUAL_CONTROL stopped", lambda: asyncio.sleep(0), watch_s=6.0)

        # --------------------------------------------------------------- RTL, land
        await probe.call("action.return_to_launch", act.return_to_launch, watch_s=6.0)
        await probe.call("action.land", act.land, watch_s=1.0)
        t_land = time.monotonic()
        await wait_until(lambda: rec.latest()["armed"] is False, 90.0, "disarmed after land")
        probe.note("landed_and_disarmed", after_s=round(time.monotonic() - t_land, 1),
                   **{k: v for k, v in rec.summary(t_land, time.monotonic()).items()
                      if k in ("texts", "mode_changes", "armed_changes")})
        await probe.call("action.disarm(on ground)", act.disarm)
        await probe.call("action.land(disarmed)", act.land, watch_s=1.5)
        await probe.call("action.return_to_launch(disarmed)", act.return_to_launch, watch_s=1.5)
        await probe.call("action.takeoff(disarmed)", act.takeoff, watch_s=1.5)
        await probe.call("action.hold(disarmed)", act.hold, watch_s=1.5)
        await probe.call("action.do_orbit(disarmed)", lambda: act.do_orbit(
            5.0, 2.0, OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER, c[0], c[1], math.nan),
            watch_s=2.0)
        await probe.call("action.arm(in orbit, on the ground)", act.arm, watch_s=1.5)
        await probe.call("action.hold(disarmed, after orbit)", act.hold, watch_s=1.5)
        await probe.call("action.arm(again)", act.arm, watch_s=2.0)
        tl = geo_of(3.0, 0.0)
        await probe.call("action.goto_location(armed, on the ground)",
                         lambda: act.goto_location(tl[0], tl[1], home_amsl + 3.0, 0.0), watch_s=6.0)
        await probe.call("action.land(2)", act.land, watch_s=1.0)
        await wait_until(lambda: rec.latest()["armed"] is False, 90.0, "disarmed after land")
        await gripper(probe, grip, out_path)
        await rec.stop()
    finally:
        if probe.out["steps"].get("gripper.release(1) [blocking]", {}).get("result") != "SUCCESS":
            plugins = []  # MAVSDK's gripper state after an IN_PROGRESS ack: do not destroy
            sdk = None
        for p in plugins:
            with contextlib.suppress(Exception):
                p.destroy()
        if sdk is not None:
            with contextlib.suppress(Exception):
                sdk.destroy()
        if tap is not None:
            tap.close()
    return probe.out


async def _maybe(fn: Callable[[], Awaitable[Any]]) -> Any:
    try:
        return await asyncio.wait_for(fn(), 5.0)
    except Exception as exc:
        return result_name(exc)


async def _amsl(tel: Any) -> float:
    p = await asyncio.wait_for(tel.position(), 5.0)
    return float(p.absolute_altitude_m - p.relative_altitude_m)


async def _hover_thrust(par: Any) -> float:
    try:
        return float(await asyncio.wait_for(par.get_param_float("MPC_THR_HOVER"), 5.0))
    except Exception:
        return 0.5


async def telemetry_rates(probe: Probe, tel: Any, window_s: float = 4.0) -> None:
    """Every Telemetry stream for ``window_s``: how many samples, and the first one."""
    counts: dict[str, int] = {}
    first: dict[str, str] = {}

    async def pump(name: str) -> None:
        gen = getattr(tel, f"subscribe_{name}")()
        async for x in gen:
            counts[name] = counts.get(name, 0) + 1
            first.setdefault(name, str(x)[:160])

    tasks = [asyncio.create_task(pump(n)) for n in STREAMS]
    await asyncio.sleep(window_s)
    for task in tasks:
        task.cancel()
    for task in tasks:
        with contextlib.suppress(BaseException):
            await task
    probe.note("telemetry.rates_hz", **{n: round(counts.get(n, 0) / window_s, 1) for n in STREAMS})
    probe.out["telemetry_first"] = first


async def params(probe: Probe, par: Any) -> None:
    await probe.call("param.get_float(MIS_TAKEOFF_ALT)", lambda: par.get_param_float("MIS_TAKEOFF_ALT"))
    await probe.call("param.get_int(SYS_AUTOSTART)", lambda: par.get_param_int("SYS_AUTOSTART"))
    await probe.call("param.get_int(MAV_SYS_ID)", lambda: par.get_param_int("MAV_SYS_ID"))
    await probe.call("param.get_int(float MIS_TAKEOFF_ALT)", lambda: par.get_param_int("MIS_TAKEOFF_ALT"))
    await probe.call("param.get_float(int SYS_AUTOSTART)", lambda: par.get_param_float("SYS_AUTOSTART"))
    await probe.call("param.set_float(MPC_XY_CRUISE,4)", lambda: par.set_param_float("MPC_XY_CRUISE", 4.0))
    await probe.call("param.get_float(MPC_XY_CRUISE)", lambda: par.get_param_float("MPC_XY_CRUISE"))
    await probe.call("param.set_int(COM_OBL_RC_ACT,5)", lambda: par.set_param_int("COM_OBL_RC_ACT", 5))
    await probe.call("param.get_int(COM_OBL_RC_ACT)", lambda: par.get_param_int("COM_OBL_RC_ACT"))
    await probe.call("param.set_int(COM_OBL_RC_ACT,0)", lambda: par.set_param_int("COM_OBL_RC_ACT", 0))
    await probe.call("param.set_float(MPC_XY_CRUISE,5)", lambda: par.set_param_float("MPC_XY_CRUISE", 5.0))
    await probe.call("param.set_int(float MPC_XY_CRUISE)", lambda: par.set_param_int("MPC_XY_CRUISE", 4))
    await probe.call("param.get_float(unknown)", lambda: par.get_param_float(UNKNOWN_PARAM), timeout_s=20.0)
    await probe.call("param.get_int(unknown)", lambda: par.get_param_int(UNKNOWN_PARAM), timeout_s=20.0)
    await probe.call("param.set_float(unknown)", lambda: par.set_param_float(UNKNOWN_PARAM, 1.0), timeout_s=20.0)
    await probe.call("param.set_int(unknown)", lambda: par.set_param_int(UNKNOWN_PARAM, 1), timeout_s=20.0)

    def keep(all_params: Any) -> dict[str, Any]:
        ints = {p.name: p.value for p in all_params.int_params}
        floats = {p.name: p.value for p in all_params.float_params}
        probe.out["all_params"] = {"int": ints, "float": floats}
        return {"int": len(ints), "float": len(floats),
                "custom": len(getattr(all_params, "custom_params", []))}

    await probe.call("param.get_all_params", par.get_all_params, timeout_s=120.0, keep=keep)


async def geofence(probe: Probe, geo: Any, raw: Any, Circle: Any, FenceType: Any,
                   GeofenceData: Any, Point: Any, Polygon: Any) -> None:
    lat, lon = 47.397742, 8.545594
    d = 0.0009
    poly = Polygon([Point(lat - d, lon - d), Point(lat + d, lon - d), Point(lat + d, lon + d),
                    Point(lat - d, lon + d)], FenceType.INCLUSION)
    circle = Circle(Point(lat, lon), 150.0, FenceType.INCLUSION)
    await probe.call("geofence.upload(polygon4+circle)",
                     lambda: geo.upload_geofence(GeofenceData([poly], [circle])), timeout_s=20.0)

    def items(v: Any) -> list[str]:
        return [f"seq={i.seq} cmd={i.command} frame={i.frame} p1={i.param1:g} type={i.mission_type}"
                for i in v]

    await probe.call("mission_raw.download_geofence", raw.download_geofence, timeout_s=20.0,
                     keep=items)
    await probe.call("geofence.clear", geo.clear_geofence, timeout_s=20.0)
    await probe.call("mission_raw.download_geofence(cleared)", raw.download_geofence,
                     timeout_s=20.0, keep=items)
    await probe.call("geofence.upload(circle only)",
                     lambda: geo.upload_geofence(GeofenceData([], [circle])), timeout_s=20.0)
    await probe.call("geofence.clear(2)", geo.clear_geofence, timeout_s=20.0)


async def mission_upload(probe: Probe, mis: Any, raw: Any, MissionItem: Any, MissionPlan: Any,
                         geo_of: Callable[[float, float], tuple[float, float]]) -> None:
    def item(n: float, e: float, alt: float, speed: float) -> Any:
        la, lo = geo_of(n, e)
        return MissionItem(latitude_deg=la, longitude_deg=lo, relative_altitude_m=alt,
                           speed_m_s=speed, is_fly_through=True, gimbal_pitch_deg=math.nan,
                           gimbal_yaw_deg=math.nan, camera_action=MissionItem.CameraAction.NONE,
                           loiter_time_s=math.nan, camera_photo_interval_s=math.nan,
                           acceptance_radius_m=2.0, yaw_deg=math.nan,
                           camera_photo_distance_m=math.nan,
                           vehicle_action=MissionItem.VehicleAction.NONE)

    plan = MissionPlan([item(10.0, 0.0, 10.0, 3.0), item(10.0, 10.0, 10.0, 3.0), item(0.0, 10.0, 10.0, 3.0)])
    await probe.call("mission.upload(3 items, speeds)", lambda: mis.upload_mission(plan), timeout_s=30.0)

    def plan_items(v: Any) -> list[str]:
        return [f"{i.latitude_deg:.6f},{i.longitude_deg:.6f} alt={i.relative_altitude_m:g} "
                f"speed={i.speed_m_s:g} through={i.is_fly_through}" for i in v.mission_items]

    await probe.call("mission.download", mis.download_mission, timeout_s=30.0, keep=plan_items)

    def raw_items(v: Any) -> list[str]:
        return [f"seq={i.seq} cmd={i.command} frame={i.frame} cur={i.current} "
                f"p1={i.param1:g} p2={i.param2:g} z={i.z:g} type={i.mission_type}" for i in v]

    await probe.call("mission_raw.download_mission", raw.download_mission, timeout_s=30.0, keep=raw_items)
    await probe.call("mission.is_mission_finished", mis.is_mission_finished)


async def offboard_all(probe: Probe, off: Any, act: Any, rec: Recorder, hover: float,
                       geo_of: Callable[[float, float], tuple[float, float]], home_amsl: float,
                       PositionNedYaw: Any, VelocityNedYaw: Any, VelocityBodyYawspeed: Any,
                       AccelerationNed: Any, Attitude: Any, AttitudeRate: Any,
                       PositionGlobalYaw: Any) -> None:
    """Each setpoint type from Hold: the setpoint, ``Offboard.start``, 4 s, ``Offboard.stop``."""
    await probe.call("offboard.start(no setpoint)", off.start)

    async def run(name: str, setter: Callable[[dict[str, Any]], Awaitable[Any]], hold_s: float = 4.0) -> None:
        here = rec.latest()
        if here["rel_alt"] < 8.0 or abs(here["ned"][0]) > 15.0 or abs(here["ned"][1]) > 15.0:
            tl = geo_of(0.0, 0.0)
            await probe.call(f"goto(reset before {name})",
                             lambda: act.goto_location(tl[0], tl[1], home_amsl + 10.0, 0.0), watch_s=0.5)
            await wait_until(lambda: rec.latest()["rel_alt"] > 9.0 and abs(rec.latest()["ned"][0]) < 3
                             and abs(rec.latest()["ned"][1]) < 3, 40.0, "back at 10 m")
            await asyncio.sleep(2.0)
            here = rec.latest()
        await probe.call(f"offboard.set_{name}", lambda: setter(here))
        await probe.call(f"offboard.start[{name}]", off.start, watch_s=0.0)

        async def stream() -> None:  # what a client does: keep setting it
            t_end = time.monotonic() + hold_s
            while time.monotonic() < t_end:
                with contextlib.suppress(Exception):
                    await setter(here)
                await asyncio.sleep(0.05)

        t0 = time.monotonic()
        await asyncio.wait_for(stream(), hold_s + 5.0)
        s = rec.summary(t0, time.monotonic())
        probe.out["steps"][f"offboard.start[{name}]"].update({"flown": s})
        probe.log(f"    flown {name}: modes={s.get('modes')} d={s.get('displacement_ned_m')} "
                  f"v={s.get('mean_velocity_ned_mps')} yaw={s.get('yaw_change_deg')} "
                  f"pitch={s.get('pitch_min_max_deg')} h={s.get('height_min_max_m')}")
        await probe.call(f"offboard.stop[{name}]", off.stop, watch_s=3.0)

    def n_e_d_yaw(h: dict[str, Any]) -> tuple[float, float, float, float]:
        return h["ned"][0], h["ned"][1], h["ned"][2], h["yaw"]

    def pos(h: dict[str, Any]) -> Awaitable[Any]:
        n, e, d, y = n_e_d_yaw(h)
        return off.set_position_ned(PositionNedYaw(n + 3.0, e, d, y))

    def vel(h: dict[str, Any]) -> Awaitable[Any]:
        return off.set_velocity_ned(VelocityNedYaw(0.0, 1.0, 0.0, h["yaw"]))

    def body(h: dict[str, Any]) -> Awaitable[Any]:
        return off.set_velocity_body(VelocityBodyYawspeed(1.0, 0.0, 0.0, 15.0))

    def posvel(h: dict[str, Any]) -> Awaitable[Any]:
        n, e, d, y = n_e_d_yaw(h)
        return off.set_position_velocity_ned(PositionNedYaw(n + 3.0, e, d, y),
                                             VelocityNedYaw(0.5, 0.0, 0.0, y))

    def posvelacc(h: dict[str, Any]) -> Awaitable[Any]:
        n, e, d, y = n_e_d_yaw(h)
        return off.set_position_velocity_acceleration_ned(
            PositionNedYaw(n, e + 3.0, d, y), VelocityNedYaw(0.0, 0.5, 0.0, y),
            AccelerationNed(0.0, 0.0, 0.0))

    def acc(h: dict[str, Any]) -> Awaitable[Any]:
        return off.set_acceleration_ned(AccelerationNed(0.5, 0.0, 0.0))

    def glob(h: dict[str, Any]) -> Awaitable[Any]:
        la, lo = geo_of(h["ned"][0] - 3.0, h["ned"][1])
        return off.set_position_global(PositionGlobalYaw(
            la, lo, h["rel_alt"], h["yaw"], PositionGlobalYaw.AltitudeType.REL_HOME))

    def att(h: dict[str, Any]) -> Awaitable[Any]:
        return off.set_attitude(Attitude(0.0, -5.0, h["yaw"], hover))

    def rate(h: dict[str, Any]) -> Awaitable[Any]:
        return off.set_attitude_rate(AttitudeRate(0.0, 0.0, 10.0, hover))

    await run("position_ned", pos)
    await run("velocity_ned", vel)
    await run("velocity_body", body)
    await run("position_velocity_ned", posvel)
    await run("position_velocity_acceleration_ned", posvelacc)
    await run("acceleration_ned", acc, hold_s=3.0)
    await run("position_global", glob)
    await run("attitude", att, hold_s=2.0)
    await run("attitude_rate", rate, hold_s=2.0)


async def gripper(probe: Probe, grip: Any, out_path: str | None) -> None:
    """Last, on the ground. PX4 answers a gripper state change IN_PROGRESS, then ACCEPTED; MAVSDK
    4.1's Gripper returns UNKNOWN on the first ack and its callback fires again on the final one
    (the process then crashed in both the asyncio and the blocking API, or the plugin's next
    call hung). So the sequence goes on the wire first, from the tap as a second ground station
    (sysid 246), then MAVSDK's own grab and release, the findings are written at once and the
    process ends before the final ack can arrive."""
    tap = probe.tap
    if tap is not None:
        M = tap.M
        for name, action, gap_s in (("release", 0, 2.0), ("release again", 0, 0.5), ("grab", 1, 0.2),
                                    ("release while grabbing", 0, 2.0), ("grab", 1, 0.2),
                                    ("grab while grabbing", 1, 2.0)):
            t0 = time.monotonic()
            tap.inject(M.MAVLink_command_long_message(tap.ap_sysid, 1, M.MAV_CMD_DO_GRIPPER, 0, 1, action,
                                                      0, 0, 0, 0, 0))
            await asyncio.sleep(gap_s)
            acks = [(round(t - t0, 3), _enum(M.enums["MAV_RESULT"], m.result), m.progress)
                    for t, d, m in tap.window(t0, time.monotonic())
                    if d == "down" and m.get_type() == "COMMAND_ACK"
                    and m.command == M.MAV_CMD_DO_GRIPPER and m.target_system == 246]
            probe.note(f"wire DO_GRIPPER {name}", acks=acks)
    sync = grip._plugin
    loop = asyncio.get_running_loop()
    for action in ("grab", "release"):
        fn = getattr(sync, action)
        await probe.call(f"gripper.{action}(1) [blocking]",
                         lambda fn=fn: loop.run_in_executor(None, fn, 1), timeout_s=5.0)
    probe.dump(out_path)
    print("gripper: findings written; ending before MAVSDK's second callback", flush=True)
    os._exit(0)


async def manual_control(probe: Probe, man: Any, act: Any) -> None:
    """ManualControl: sticks streamed at 20 Hz, Position mode, a forward deflection."""
    sticks = [0.0, 0.0, 0.5, 0.0]
    stop = asyncio.Event()

    async def stream() -> None:
        while not stop.is_set():
            with contextlib.suppress(Exception):
                await man.set_manual_control_input(*sticks)
            await asyncio.sleep(0.05)

    task = asyncio.create_task(stream())
    try:
        await probe.call("manual.start_position_control(no input yet)", man.start_position_control)
        await asyncio.sleep(1.0)
        await probe.call("manual.start_position_control", man.start_position_control, watch_s=3.0)
        sticks[0] = 0.5
        await probe.call("manual.input(x=0.5) 3 s", lambda: asyncio.sleep(0), watch_s=3.0)
        sticks[0] = 0.0
        await probe.call("manual.input(centred) 3 s", lambda: asyncio.sleep(0), watch_s=3.0)
        await probe.call("manual.start_altitude_control", man.start_altitude_control, watch_s=2.0)
        await probe.call("action.hold(after manual)", act.hold, watch_s=1.0)
    finally:
        stop.set()
        await asyncio.wait_for(task, 5.0)


# ------------------------------------------------------------------------------------------------
# comparing two probes
# ------------------------------------------------------------------------------------------------
def compare(a_path: str, b_path: str) -> int:
    with open(a_path, encoding="utf-8") as f:
        a = json.load(f)
    with open(b_path, encoding="utf-8") as f:
        b = json.load(f)
    names = list(dict.fromkeys([*a["steps"], *b["steps"]]))
    print(f"{'step':40s} | {a_path} | {b_path}")
    for n in names:
        sa, sb = a["steps"].get(n, {}), b["steps"].get(n, {})
        ra, rb = _row(sa), _row(sb)
        mark = "  " if ra == rb else "!="
        print(f"{mark} {n:38s} | {ra} | {rb}")
    pa, pb = a.get("all_params", {}), b.get("all_params", {})
    if pa and pb:
        na = set(pa.get("int", {})) | set(pa.get("float", {}))
        nb = set(pb.get("int", {})) | set(pb.get("float", {}))
        print(f"params: {len(na)} vs {len(nb)}; only in the first: {len(na - nb)}; "
              f"only in the second: {len(nb - na)}")
    return 0


def _row(s: dict[str, Any]) -> str:
    if not s:
        return "-"
    if "result" not in s:
        return json.dumps({k: v for k, v in s.items() if k not in ("texts",)})[:120]
    acks = s.get("wire", {}).get("acks", [])
    parts = [s["result"]]
    if acks:
        parts.append(",".join(f"{x['result']}" for x in acks[:3]))
    if s.get("modes"):
        parts.append(">".join(s["modes"]))
    flown = s.get("flown")
    if flown:
        parts.append("flown " + ">".join(flown.get("modes", [])) + f" d={flown.get('displacement_ned_m')}")
    return " ".join(parts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", default="udpin://0.0.0.0:14541")
    ap.add_argument("--tap", action="store_true", help="record the MAVLink on the wire (relay)")
    ap.add_argument("--out", help="write the findings as JSON here")
    ap.add_argument("--connect-timeout-s", type=float, default=30.0)
    ap.add_argument("--compare", nargs=2, metavar=("A.json", "B.json"))
    args = ap.parse_args(argv)
    if args.compare:
        return compare(*args.compare)
    asyncio.run(run_probe(args.url, args.tap, args.connect_timeout_s, args.out))
    sys.stdout.flush()
    os._exit(0)  # MAVSDK may be left in a state its destructor hangs in (gripper, above)


if __name__ == "__main__":
    sys.exit(main())
