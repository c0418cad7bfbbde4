"""The PX4-like emulator against the real PX4 v1.16 traffic recorded in
``../shared/data/px4_sitl_tlogs`` (fixture ``px4_tlogs``; skipped when absent), and its
MAVLink protocol with a bare pymavlink client.

The recorded scenarios are replayed with the same client (MAVSDK 4.1 as a ground station,
here through the ``mavsdk`` driver) and the emulator's answers are compared with PX4's:
HEARTBEAT mode/flag/status sequences, landed states, ACK results, status texts, mission
protocol, message rates and what happens when the setpoint stream stops.
"""

from __future__ import annotations

import asyncio
import math
import os
import re
import socket
import statistics
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from eaglemission.drivers.vehicles import px4
from eaglemission.lab.vehicles.emulator.emulator import (
    PX4_ONBOARD_RATES_HZ,
    EmulatorConfig,
    Px4Emulator,
    mavlink,
    parse_link,
    stream_rates_hz,
)
from eaglemission.lab.vehicles.emulator.messages import Streams
from emulator_support import flying_pair, scenario, wait_for

from eaglemission.errors import ConfigError
from eaglemission.types import FlightMode, Setpoint, Waypoint

pytestmark = pytest.mark.machine  # emulator processes, UDP links (tests/conftest.py)

M = mavlink


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
def hb_sequence(msgs: list[Any]) -> list[tuple[int, int, int]]:
    """(base_mode, custom_mode, system_status) of HEARTBEATs, consecutive repeats removed."""
    out: list[tuple[int, int, int]] = []
    for m in msgs:
        if m.get_type() != "HEARTBEAT":
            continue
        key = (m.base_mode, m.custom_mode, m.system_status)
        if not out or out[-1] != key:
            out.append(key)
    return out


ARMED_HOLD = (px4.base_mode(FlightMode.HOLD, True), px4.custom_mode(FlightMode.HOLD),
              M.MAV_STATE_ACTIVE)


def assert_same_modes(ours: list[Any], ref: list[Any], transients: frozenset[Any] = frozenset()) -> None:
    """PX4's HEARTBEAT states (recorded at 1 Hz) appear in our (on-change) sequence in the same
    order, and we show no state PX4 did not, except short ``transients`` 1 Hz sampling missed
    on PX4 (e.g. armed HOLD for the few ms between arm and takeoff)."""
    a, b = hb_sequence(ours), hb_sequence(ref)
    it = iter(a)
    assert all(any(x == y for y in it) for x in b), f"PX4 {b} is not a subsequence of ours {a}"
    extra = set(a) - set(b) - set(transients)
    assert not extra, f"states PX4 never showed: {extra}"


def distinct(values: list[Any]) -> list[Any]:
    out: list[Any] = []
    for v in values:
        if not out or out[-1] != v:
            out.append(v)
    return out


def texts(msgs: list[Any]) -> list[str]:
    """STATUSTEXT texts, chunks joined, tab removed, numbers masked ('#')."""
    chunks: dict[int, list[str]] = {}
    order: list[int] = []
    for m in msgs:
        if m.get_type() != "STATUSTEXT":
            continue
        if m.id not in chunks:
            order.append(m.id)
            chunks[m.id] = []
        chunks[m.id].append(m.text)
    out = []
    for i in order:
        t = "".join(chunks[i]).replace("\t", "").strip()
        if t.startswith("[logger]"):
            continue
        out.append(re.sub(r"\d+(\.\d+)?", "#", t))
    return out


def out_msgs(emu: Px4Emulator) -> list[Any]:
    return [t.msg for t in list(emu.traffic) if t.direction == "out"]


def recorded(px4_tlogs: Path, name: str) -> list[Any]:
    return [m for _, m in scenario(px4_tlogs, name)[0]]


class RawClient:
    """A bare pymavlink ground station talking to the emulator through raw bytes."""

    def __init__(self, emu: Px4Emulator) -> None:
        self.emu = emu
        self.mav = M.MAVLink(None, srcSystem=245, srcComponent=190)
        self.parser = M.MAVLink(None, srcSystem=245, srcComponent=190)
        self.parser.robust_parsing = True
        self.rx: list[tuple[float, Any]] = []
        emu.set_output(self._on_bytes)

    def _on_bytes(self, data: bytes) -> None:
        for m in self.parser.parse_buffer(data) or []:
            self.rx.append((time.monotonic(), m))

    def send(self, msg: Any) -> None:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.emu.feed(data)

    def command(self, cmd: int, *params: float) -> None:
        p = list(params) + [math.nan] * (7 - len(params))
        self.send(M.MAVLink_command_long_message(1, 1, cmd, 0, *p))

    def of_type(self, kind: str) -> list[Any]:
        return [m for _, m in list(self.rx) if m.get_type() == kind]

    def wait(self, kind: str, count: int = 1, timeout_s: float = 3.0) -> list[Any]:
        deadline = time.monotonic() + timeout_s
        while len(self.of_type(kind)) < count:
            if time.monotonic() > deadline:
                raise AssertionError(f"{count} x {kind} not received within {timeout_s} s "
                                     f"(got {len(self.of_type(kind))})")
            time.sleep(0.005)
        return self.of_type(kind)


@pytest.fixture
def raw_emulator() -> Any:
    emu = Px4Emulator(EmulatorConfig(speedup=5.0), record=True)
    client = RawClient(emu)
    emu.start()
    yield emu, client
    emu.stop()


# ---------------------------------------------------------------------------------------------
# PX4 facts (pure)
# ---------------------------------------------------------------------------------------------
def test_heartbeat_flags_and_modes_match_every_recorded_heartbeat(px4_tlogs: Path) -> None:
    seen = set()
    for name in "abc":
        for m in recorded(px4_tlogs, name):
            if m.get_type() != "HEARTBEAT":
                continue
            assert (m.type, m.autopilot) == (M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4)
            mode = px4.decode_custom_mode(m.custom_mode)
            armed = bool(m.base_mode & px4.FLAG_ARMED)
            assert mode != FlightMode.UNKNOWN, hex(m.custom_mode)
            assert px4.custom_mode(mode) == m.custom_mode
            assert px4.base_mode(mode, armed) == m.base_mode, (mode, armed, hex(m.base_mode))
            seen.add((mode, armed))
    # the recordings cover these combinations (so the check above is not vacuous)
    assert {(FlightMode.HOLD, False), (FlightMode.TAKEOFF, True), (FlightMode.OFFBOARD, True),
            (FlightMode.POSCTL, True), (FlightMode.MISSION, True),
            (FlightMode.RETURN_TO_LAUNCH, True), (FlightMode.LAND, True),
            (FlightMode.OFFBOARD, False)} <= seen


def test_param_bytewise_encoding_round_trips_recorded_int_params(px4_tlogs: Path) -> None:
    ints = [m for m in recorded(px4_tlogs, "c") if m.get_type() == "PARAM_VALUE"
            and m.param_type == px4.PARAM_INT32]
    assert ints
    by_name = {m.param_id: px4.decode_param(m.param_value, m.param_type) for m in ints}
    assert by_name["CAL_ACC0_ID"] == 1310988 and by_name["CAL_ACC0_ROT"] == -1
    for v in (0, 1, -1, 10040, 2**31 - 1):
        assert px4.decode_param(px4.encode_param(v, px4.PARAM_INT32), px4.PARAM_INT32) == v


# ---------------------------------------------------------------------------------------------
# Recorded scenarios replayed through MAVSDK
# ---------------------------------------------------------------------------------------------
async def test_scenario_a_takeoff_hold_land_like_px4(px4_tlogs: Path) -> None:
    async with flying_pair(8.0, record=True) as (emu, v, clock):
        await v.arm()
        await v.takeoff(5.0)
        await wait_for(lambda: v.state().relative_altitude_m > 4.5, 20.0, "climb to 4.5 m")
        await clock.sleep(5.0)
        await v.land()
        await wait_for(lambda: not v.state().in_air, 20.0, "landed")
        await v.disarm()
        await clock.sleep(1.0)
    ours, ref = out_msgs(emu), recorded(px4_tlogs, "a")
    assert_same_modes(ours, ref)
    landed = lambda msgs: distinct([m.landed_state for m in msgs  # noqa: E731
                                    if m.get_type() == "EXTENDED_SYS_STATE"])
    assert landed(ours) == landed(ref)
    assert texts(ours) == texts(ref)
    # every client command was acknowledged ACCEPTED (as all were by PX4)
    ref_acks = {m.result for m in ref if m.get_type() == "COMMAND_ACK"}
    assert ref_acks == {M.MAV_RESULT_ACCEPTED}
    cmds = [t.msg for t in emu.traffic if t.direction == "in"
            and t.msg.get_type() in ("COMMAND_LONG", "COMMAND_INT")]
    acks = [m for m in ours if m.get_type() == "COMMAND_ACK"]
    assert Counter(m.command for m in cmds) == Counter(m.command for m in acks)
    assert {m.result for m in acks} == {M.MAV_RESULT_ACCEPTED}
    # PARAM_SET MIS_TAKEOFF_ALT answered with two PARAM_VALUEs, as PX4 does; the driver reads
    # it before (it differs) and after the set (PARAM_REQUEST_READ: one more each), the
    # recorded plain MAVSDK client did not
    pv = [m for m in ours if m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT"]
    ref_pv = [m for m in ref if m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT"]
    reads = [t.msg for t in emu.traffic if t.direction == "in"
             and t.msg.get_type() == "PARAM_REQUEST_READ" and t.msg.param_id == "MIS_TAKEOFF_ALT"]
    assert len(ref_pv) == 2 and len(reads) == 2
    assert len(pv) == len(ref_pv) + len(reads)
    assert pv[0].param_value != 5.0 and {m.param_value for m in pv[1:]} == {5.0}


async def test_scenario_c_mission_then_rtl_like_px4(px4_tlogs: Path) -> None:
    async with flying_pair(10.0, record=True) as (emu, v, clock):
        await v.set_param("RTL_RETURN_ALT", 10.0)
        await v.upload_mission([Waypoint(20.0, 0.0, 10.0, 5.0), Waypoint(20.0, 20.0, 10.0, 3.0),
                                Waypoint(0.0, 20.0, 10.0, 5.0)])
        await v.arm()
        await v.start_mission()
        await wait_for(lambda: v.mission_progress().finished, 30.0, "mission 3/3")
        await v.return_to_launch()
        await wait_for(lambda: not v.state().armed, 30.0, "RTL landed and disarmed")
        await clock.sleep(1.0)
    ours, ref = out_msgs(emu), recorded(px4_tlogs, "c")
    assert_same_modes(ours, ref, frozenset({ARMED_HOLD}))
    reached = lambda msgs: distinct([m.seq for m in msgs  # noqa: E731
                                     if m.get_type() == "MISSION_ITEM_REACHED"])
    assert reached(ours) == reached(ref) == [1, 3, 5]  # the DO_CHANGE_SPEED after each waypoint
    current = lambda msgs: distinct([(m.seq, m.total) for m in msgs  # noqa: E731
                                     if m.get_type() == "MISSION_CURRENT"])
    assert current(ours) == current(ref)
    n_req = sum(m.get_type() == "MISSION_REQUEST_INT" for m in ours)
    assert n_req == sum(m.get_type() == "MISSION_REQUEST_INT" for m in ref) == 6
    mack = [m for m in ours if m.get_type() == "MISSION_ACK"]
    assert [m.type for m in mack] == [M.MAV_MISSION_ACCEPTED]
    assert texts(ours) == texts(ref)
    set_mode_acks = [m for m in ours if m.get_type() == "COMMAND_ACK"
                     and m.command == M.MAV_CMD_DO_SET_MODE]
    assert len(set_mode_acks) == 2 * 2  # start_mission and RTL, each acknowledged twice (PX4)


def _sim_times(emu: Px4Emulator, direction: str, kind: str) -> list[tuple[float, Any]]:
    return [(t.sim_s, t.msg) for t in list(emu.traffic)
            if t.direction == direction and t.msg.get_type() == kind]


async def test_scenario_b_setpoint_stream_stops_like_px4(px4_tlogs: Path) -> None:
    """The client dies in OFFBOARD: PX4 fails over to Position mode after COM_OF_LOSS_T, sinks
    without RC input, lands, disarms and shows OFFBOARD/UNINIT again."""
    px4_msgs, client_msgs, _ = scenario(px4_tlogs, "b")
    t_last_sp = max(t for t, m in client_msgs if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED")
    t_failsafe = min(t for t, m in px4_msgs if m.get_type() == "STATUSTEXT"
                     and "Failsafe" in m.text) - t_last_sp
    posctl = px4.custom_mode(FlightMode.POSCTL)
    hb_pos = [t for t, m in px4_msgs if m.get_type() == "HEARTBEAT" and m.custom_mode == posctl]
    ref_vz = [m.vz / 100 for t, m in px4_msgs if m.get_type() == "GLOBAL_POSITION_INT"
              and hb_pos[0] + 0.5 <= t and m.relative_alt > 500]
    ref_disarm = min(t for t, m in px4_msgs if m.get_type() == "HEARTBEAT"
                     and t > t_last_sp and not m.base_mode & px4.FLAG_ARMED) - t_last_sp

    # watchdog off: this replays PX4's own failsafe (the client process is gone)
    async with flying_pair(5.0, record=True, vehicle={"watchdog_timeout_s": 10.0}) as (emu, v, clock):
        await v.arm()
        await v.takeoff(5.0)
        await wait_for(lambda: v.state().relative_altitude_m > 4.5, 20.0, "climb")
        await wait_for(lambda: v.state().flight_mode == FlightMode.HOLD, 5.0, "HOLD")
        await clock.sleep(1.0)
        s = v.state()
        goal = Setpoint(s.position_ned_m[0] + 10.0, s.position_ned_m[1], s.position_ned_m[2],
                        s.yaw_deg)
        await v.start_offboard(goal)
        while math.dist(v.state().position_ned_m, goal.position_ned_m) > 0.5:
            await v.set_setpoint(goal)
            await clock.sleep(0.05)
        await clock.sleep(2.0)
        emu.inject_link_loss(3600.0, direction="uplink")  # the client process dies
        await wait_for(lambda: not emu.snapshot().armed, 10.0, "failsafe landing and disarm")
        await clock.sleep(2.0)
    sps = _sim_times(emu, "in", "SET_POSITION_TARGET_LOCAL_NED")
    last_sp = max(t for t, _ in sps)
    fs = [t for t, m in _sim_times(emu, "out", "STATUSTEXT") if "Failsafe" in m.text]
    assert fs and abs((fs[0] - last_sp) - t_failsafe) < 0.2, (fs[0] - last_sp, t_failsafe)
    ours_hb = [(t, m) for t, m in _sim_times(emu, "out", "HEARTBEAT")]
    assert_same_modes([m for _, m in ours_hb], [m for _, m in px4_msgs])
    our_pos = [t for t, m in ours_hb if m.custom_mode == posctl]
    vz = [m.vz / 100 for t, m in _sim_times(emu, "out", "GLOBAL_POSITION_INT")
          if our_pos[0] + 0.5 <= t and m.relative_alt > 500]
    assert abs(statistics.median(vz) - statistics.median(ref_vz)) < 0.15, (
        statistics.median(vz), statistics.median(ref_vz))
    disarm = min(t for t, m in ours_hb if t > last_sp and not m.base_mode & px4.FLAG_ARMED) - last_sp
    # "Landing detected" after touchdown varies between recordings (b: ~1.3 s, e: 3.2-6.9 s;
    # the emulator uses e's median 3.9 s), so the disarm lands within 3 s of b's
    assert abs(disarm - ref_disarm) < 3.0, (disarm, ref_disarm)


# ---------------------------------------------------------------------------------------------
# Rates
# ---------------------------------------------------------------------------------------------
RATE_CHECKED = ("ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED",
                "GPS_RAW_INT", "SYS_STATUS", "HEARTBEAT", "MISSION_CURRENT")


def _recorded_rates_hz(px4_tlogs: Path) -> dict[str, float]:
    ref = recorded(px4_tlogs, "a")
    span = scenario(px4_tlogs, "a")[0][-1][0]
    return {k: n / span for k, n in Counter(m.get_type() for m in ref).items()}


def test_stream_schedule_matches_px4_onboard_profile(px4_tlogs: Path) -> None:
    """The schedule itself, on a virtual wall clock ticking at ``tick_hz``: what the emulator
    sends per second when its loop keeps time, against PX4's recorded rates (scenario a)."""
    cfg = EmulatorConfig()
    rates = stream_rates_hz(cfg)
    streams = Streams(rates)
    ticks = int(20.0 * cfg.tick_hz)
    sent: Counter[str] = Counter()
    for k in range(ticks):
        sent.update(streams.due(k / cfg.tick_hz))
    span_s = ticks / cfg.tick_hz
    ref_hz = _recorded_rates_hz(px4_tlogs)
    for name in RATE_CHECKED:
        ref = ref_hz[name] * (cfg.speedup if name == "HEARTBEAT" else 1.0)
        assert sent[name] / span_s == pytest.approx(ref, rel=0.1, abs=0.1), (name, sent[name])


def test_stream_rates_delivered_live(px4_tlogs: Path, raw_emulator: Any) -> None:
    """The running emulator over a real byte link. Its Python loop may fall behind on a loaded
    machine (CI measured ATTITUDE at 64 of 100 Hz) and then drops, as PX4 does, rather than
    bursts: every stream arrives, none faster than PX4; the exact rates are the schedule test's."""
    emu, client = raw_emulator
    ref_hz = _recorded_rates_hz(px4_tlogs)
    time.sleep(2.0)
    t = [ts for ts, _ in client.rx]
    ours = Counter(m.get_type() for _, m in client.rx)
    window = t[-1] - t[0]
    for name in RATE_CHECKED:
        hz = ours[name] / window
        # HEARTBEAT runs on the emulator's clock (1 Hz of emulator time), the others in wall time
        ref = ref_hz[name] * (emu.config.speedup if name == "HEARTBEAT" else 1.0)
        assert 0.3 * ref <= hz <= 1.15 * ref + 0.5, (name, hz, ref)
    # EXTENDED_SYS_STATE: 5 Hz until MAVSDK asks for 1 Hz (SET_MESSAGE_INTERVAL 245, 1 s)
    assert ours["EXTENDED_SYS_STATE"] / window == pytest.approx(5.0, rel=0.3)
    client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 245, 1_000_000)
    ack = client.wait("COMMAND_ACK")[-1]
    assert ack.result == M.MAV_RESULT_ACCEPTED
    n0 = len(client.of_type("EXTENDED_SYS_STATE"))
    time.sleep(2.5)
    assert len(client.of_type("EXTENDED_SYS_STATE")) - n0 in (2, 3)


# ---------------------------------------------------------------------------------------------
# Protocol with a bare pymavlink client
# ---------------------------------------------------------------------------------------------
def test_every_command_is_acknowledged(raw_emulator: Any) -> None:
    emu, client = raw_emulator
    client.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 3)  # hold, accepted even on the ground
    client.command(31000)  # not a command PX4 knows
    client.command(M.MAV_CMD_DO_GRIPPER, 1, 7)  # not a gripper action: denied
    acks = client.wait("COMMAND_ACK", 4)
    assert [(a.command, a.result) for a in acks] == [
        (M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_ACCEPTED), (M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_ACCEPTED),
        (31000, M.MAV_RESULT_UNSUPPORTED), (M.MAV_CMD_DO_GRIPPER, M.MAV_RESULT_DENIED)]
    assert all((a.target_system, a.target_component) == (245, 190) for a in acks)
    emu.deny_next_command("COMPONENT_ARM_DISARM")
    client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    acks = client.wait("COMMAND_ACK", 6)[-2:]
    assert [a.result for a in acks] == [M.MAV_RESULT_DENIED, M.MAV_RESULT_ACCEPTED]
    assert emu.snapshot().armed


def test_params_two_replies_and_int_bytewise(raw_emulator: Any) -> None:
    emu, client = raw_emulator
    client.send(M.MAVLink_param_set_message(1, 1, b"COM_OF_LOSS_T", 2.5, px4.PARAM_REAL32))
    pv = client.wait("PARAM_VALUE", 2)
    assert [(m.param_id, m.param_value) for m in pv] == [("COM_OF_LOSS_T", 2.5)] * 2
    assert emu.param("COM_OF_LOSS_T") == 2.5
    client.send(M.MAVLink_param_request_read_message(1, 1, b"SYS_AUTOSTART", -1))
    m = client.wait("PARAM_VALUE", 3)[-1]
    assert m.param_type == px4.PARAM_INT32 and px4.decode_param(m.param_value, m.param_type) == 10040
    client.send(M.MAVLink_param_set_message(1, 1, b"COM_OBL_RC_ACT",
                                            px4.encode_param(5, px4.PARAM_INT32), px4.PARAM_INT32))
    client.wait("PARAM_VALUE", 5)
    assert emu.param("COM_OBL_RC_ACT") == 5


def test_mission_upload_download_round_trip(raw_emulator: Any) -> None:
    emu, client = raw_emulator
    cur = client.wait("MISSION_CURRENT")[-1]
    assert cur.total == 65535  # nothing uploaded yet (recorded)
    items = [M.MAVLink_mission_item_int_message(1, 1, i, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                M.MAV_CMD_NAV_WAYPOINT, int(i == 0), 1, 0, 1, 0,
                                                math.nan, 473977420 + 1000 * i, 85455940, 7.0)
             for i in range(3)]
    client.send(M.MAVLink_mission_count_message(1, 1, 3, 0))
    # PX4 asks for the first item in its legacy float mode (recorded c); an item sent as
    # MISSION_ITEM_INT switches it to MISSION_REQUEST_INT for the rest
    assert client.wait("MISSION_REQUEST")[-1].seq == 0
    client.send(items[0])
    for i in range(1, 3):
        req = client.wait("MISSION_REQUEST_INT", i)[-1]
        assert req.seq == i
        client.send(items[i])
    ack = client.wait("MISSION_ACK")[-1]
    assert ack.type == M.MAV_MISSION_ACCEPTED
    assert emu.snapshot().mission_count == 3
    client.send(M.MAVLink_mission_request_list_message(1, 1, 0))
    assert client.wait("MISSION_COUNT")[-1].count == 3
    for i in range(3):
        client.send(M.MAVLink_mission_request_int_message(1, 1, i, 0))
    got = client.wait("MISSION_ITEM_INT", 3)
    assert [(m.seq, m.x, m.z) for m in got] == [(i, 473977420 + 1000 * i, 7.0) for i in range(3)]


def test_link_delay_and_loss(raw_emulator: Any) -> None:
    emu, client = raw_emulator
    emu.set_link_delay(0.3)
    t0 = time.monotonic()
    client.command(M.MAV_CMD_REQUEST_MESSAGE, 242)
    client.wait("COMMAND_ACK")
    assert time.monotonic() - t0 >= 0.55  # 0.3 s each way
    emu.set_link_delay(0.0)
    time.sleep(0.4)
    emu.inject_link_loss(0.5)
    n = len(client.rx)
    time.sleep(0.4)
    assert len(client.rx) == n  # nothing comes out
    client.command(M.MAV_CMD_REQUEST_MESSAGE, 242)  # and nothing gets in
    time.sleep(0.3)
    assert len(client.rx) > n
    assert len(client.of_type("COMMAND_ACK")) == 1


def test_gps_loss_and_battery_faults(raw_emulator: Any) -> None:
    emu, client = raw_emulator
    emu.inject_gps_loss(6.0)  # emulator seconds: 1.2 s of wall time at speed-up 5
    emu.set_battery_fraction(0.42)
    time.sleep(0.1)
    n = len(client.rx)
    time.sleep(0.3)
    new = [m for _, m in client.rx[n:]]
    sys_status = [m for m in new if m.get_type() == "SYS_STATUS"][-1]
    assert not sys_status.onboard_control_sensors_health & M.MAV_SYS_STATUS_SENSOR_GPS
    assert not sys_status.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK
    assert [m for m in new if m.get_type() == "GPS_RAW_INT"][-1].fix_type < 3
    assert sys_status.battery_remaining == 42
    time.sleep(1.0)  # 7 s of emulator time: the fix is back
    n = len(client.rx)
    time.sleep(0.3)
    sys_status = [m for _, m in client.rx[n:] if m.get_type() == "SYS_STATUS"][-1]
    assert sys_status.onboard_control_sensors_health & M.MAV_SYS_STATUS_SENSOR_GPS


async def test_pilot_mode_change_and_gps_loss_in_flight() -> None:
    async with flying_pair(8.0) as (emu, v, clock):
        await v.arm()
        await v.takeoff(4.0)
        await wait_for(lambda: v.state().flight_mode == FlightMode.HOLD and v.state().in_air, 20.0,
                       "hover")
        emu.pilot_take_control(FlightMode.POSCTL)
        await wait_for(lambda: v.state().flight_mode == FlightMode.POSCTL, 3.0, "POSCTL")
        alt = v.state().relative_altitude_m
        await clock.sleep(3.0)
        assert abs(v.state().relative_altitude_m - alt) < 0.5  # a pilot holds it (sticks centred)
        assert any(e.kind == "mode" and e.data.get("source") == "autopilot" for e in v.events())
        emu.inject_gps_loss(30.0)
        await wait_for(lambda: v.state().flight_mode == FlightMode.LAND, 5.0, "GPS-loss landing")
        await wait_for(lambda: not v.state().armed, 20.0, "landed and disarmed")
        assert any("Failsafe" in e.text for e in v.events() if e.kind == "status")


def test_link_url_parsing() -> None:
    assert parse_link("udpin://0.0.0.0:14550") == ("udpin", "0.0.0.0", 14550)
    assert parse_link("udpout:127.0.0.1:14540") == ("udpout", "127.0.0.1", 14540)
    for bad in ("udp://:14540", "serial:///dev/ttyACM0", "udpin://0.0.0.0"):
        with pytest.raises(ConfigError, match="udpin://HOST:PORT"):
            parse_link(bad)
    with pytest.raises(ConfigError, match="unknown PX4 parameters"):
        Px4Emulator(EmulatorConfig(params={"NOT_A_PARAM": 1.0}))
    assert set(PX4_ONBOARD_RATES_HZ) >= {"HEARTBEAT", "ATTITUDE", "GLOBAL_POSITION_INT"}


def test_cli_over_udp_stops_on_sigterm() -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(5.0)
    port = sock.getsockname()[1]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "eaglemission.cli", "sitl-vehicle", "--mavlink",
                             f"udpout://127.0.0.1:{port}", "--duration-s", "30"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    try:
        parser = M.MAVLink(None)
        parser.robust_parsing = True
        kinds: set[str] = set()
        deadline = time.monotonic() + 20.0
        while "HEARTBEAT" not in kinds and time.monotonic() < deadline:
            data, _ = sock.recvfrom(4096)
            kinds |= {m.get_type() for m in parser.parse_buffer(data) or []}
        assert "HEARTBEAT" in kinds
        proc.terminate()  # SIGTERM
        assert proc.wait(timeout=5.0) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        sock.close()
    assert "emulator stopped" in proc.stdout.read().decode()  # type: ignore[union-attr]


async def test_emulator_keeps_flying_while_the_client_loop_is_blocked() -> None:
    async with flying_pair(4.0) as (emu, v, _clock):
        await v.arm()
        t0 = emu.sim_time_s
        time.sleep(0.5)  # block this event loop: the emulator lives in its own thread
        assert emu.sim_time_s - t0 >= 1.0
        await asyncio.sleep(0)


async def test_battery_drain_triggers_px4_low_battery_action() -> None:
    async with flying_pair(5.0, emulator={"params": {"COM_LOW_BAT_ACT": 3}}) as (emu, v, clock):
        await v.arm()
        await v.takeoff(3.0)
        await wait_for(lambda: v.state().in_air, 20.0, "in air")
        emu.set_battery_fraction(0.09)
        emu.set_battery_drain(0.01)  # 1 %/s: critical (7 %) in 2 s of emulator time
        await wait_for(lambda: v.state().flight_mode == FlightMode.RETURN_TO_LAUNCH, 5.0,
                       "return at critical battery (COM_LOW_BAT_ACT=3)")
        # BATTERY_STATUS streams on its own timer: the mode (next HEARTBEAT) may show first
        await wait_for(lambda: v.state().battery_remaining < 0.08, 2.0,
                       "battery telemetry below 8 % with the return")
        texts_seen = [e.text for e in v.events() if e.kind == "status"]
        assert "Critical battery level" in texts_seen and "Failsafe activated" in texts_seen
