"""The MAVSDK driver beyond the contract suite: bounded connect, URL checks, the offboard rules
PX4 needs (first setpoint, streamed speed-limited steps, yaw wrap, frames), telemetry rates
and stamping, parameters, gripper, typed errors, and the watchdog thread on its own."""

from __future__ import annotations

import asyncio
import math
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from eaglemission.drivers.vehicles.mavsdk.vehicle import (
    MavsdkVehicle,
    parse_url,
    step_towards,
)
from eaglemission.drivers.vehicles.mavsdk.watchdog import OffboardWatchdog
from eaglemission.lab.vehicles.emulator.emulator import mavlink as M
from emulator_support import flying_pair, wait_for

from eaglemission import registry
from eaglemission.errors import TimeoutError_, VehicleError
from eaglemission.geometry import wrap_deg
from eaglemission.interfaces import Vehicle
from eaglemission.types import FlightMode, Setpoint

pytestmark = pytest.mark.machine  # MAVSDK over UDP links (tests/conftest.py)

REPO = Path(__file__).resolve().parents[3]


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# ---------------------------------------------------------------------------------------------
# plugin, URLs, unreachable autopilots
# ---------------------------------------------------------------------------------------------
def test_registered_plugin_conforms() -> None:
    cls = registry.get("vehicles", "mavsdk")
    assert cls is MavsdkVehicle
    assert isinstance(MavsdkVehicle(), Vehicle)


def test_only_the_driver_imports_mavsdk() -> None:
    offenders = []
    for folder in ("eaglemission", "drivers", "detectors", "estimators", "missions"):
        for path in (REPO / folder).rglob("*.py"):
            if path.name == "mavsdk_vehicle.py":
                continue
            for line in path.read_text(errors="ignore").splitlines():
                s = line.strip()
                if s.startswith(("import mavsdk", "from mavsdk")):
                    offenders.append(f"{path.relative_to(REPO)}: {s}")
    assert not offenders, offenders


@pytest.mark.parametrize("url", ["udp://:14540", "udpin://:14540", "http://x:1", "14540",
                                 "tcpout://localhost"])
async def test_bad_urls_fail_at_once_with_the_spelling(url: str) -> None:
    v = MavsdkVehicle(MavsdkVehicle.Config(url=url))
    t0 = time.monotonic()
    with pytest.raises(VehicleError, match="udpin://0.0.0.0:14540") as info:
        await v.connect()
    assert info.value.result == "CONNECTION_ERROR" and info.value.origin == "connect()"
    assert time.monotonic() - t0 < 0.5
    assert parse_url("serial:///dev/ttyACM0:921600") == "serial"


@pytest.mark.parametrize("scheme", ["udpin", "udpout"])
async def test_unreachable_url_fails_within_its_timeout(scheme: str) -> None:
    host = "127.0.0.1"
    url = f"{scheme}://{host}:{_free_udp_port()}"
    v = MavsdkVehicle(MavsdkVehicle.Config(url=url, connect_timeout_s=1.0))
    t0 = time.monotonic()
    with pytest.raises(TimeoutError_) as info:
        await v.connect()
    elapsed = time.monotonic() - t0
    assert 0.9 <= elapsed < 2.5, elapsed
    msg = str(info.value)
    assert "no autopilot heard on " + url in msg and "within 1 s" in msg
    assert "udpin://0.0.0.0:14540" in msg  # says what to check
    with pytest.raises(VehicleError, match="connect"):
        v.state()
    await v.close()


async def test_raw_needs_a_peer_and_virtual_clocks_are_refused() -> None:
    with pytest.raises(VehicleError, match="mavlink_peer"):
        await MavsdkVehicle(MavsdkVehicle.Config(url="raw://")).connect()
    from eaglemission.clock import ManualClock

    with pytest.raises(VehicleError, match="wall time"):
        await MavsdkVehicle(MavsdkVehicle.Config(url="raw://"), clock=ManualClock(),
                            mavlink_peer=object()).connect()  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------
# pure offboard step
# ---------------------------------------------------------------------------------------------
def test_step_towards_limits_speed_and_turns_the_short_way() -> None:
    rng = np.random.RandomState(3)
    for _ in range(200):
        cur = Setpoint(*rng.uniform(-50, 50, 2), -rng.uniform(1, 20), rng.uniform(-180, 180))
        goal = Setpoint(*rng.uniform(-50, 50, 2), -rng.uniform(1, 20), rng.uniform(-180, 180))
        dt = rng.uniform(0.01, 0.2)
        nxt = step_towards(cur, goal, dt, max_speed_mps=3.0, max_vertical_speed_mps=1.0,
                           max_yaw_rate_degps=45.0)
        assert math.hypot(nxt.north_m - cur.north_m, nxt.east_m - cur.east_m) <= 3.0 * dt + 1e-9
        assert abs(nxt.down_m - cur.down_m) <= 1.0 * dt + 1e-9
        turn = wrap_deg(nxt.yaw_deg - cur.yaw_deg)
        assert abs(turn) <= 45.0 * dt + 1e-9
        want = wrap_deg(goal.yaw_deg - cur.yaw_deg)
        assert turn == 0 or math.copysign(1, turn) == math.copysign(1, want)  # short way round
    # close goals are reached exactly
    a, b = Setpoint(0, 0, -5, 170), Setpoint(0.01, 0, -5, -175)
    assert step_towards(a, b, 0.1, max_speed_mps=3, max_vertical_speed_mps=1,
                        max_yaw_rate_degps=200) == Setpoint(0.01, 0, -5, -175)


# ---------------------------------------------------------------------------------------------
# against the emulator
# ---------------------------------------------------------------------------------------------
async def test_telemetry_rates_requested_and_stamped_on_receipt() -> None:
    async with flying_pair(4.0, record=True) as (emu, v, clock):
        intervals = {int(m.param1): m.param2 for m in emu.received("COMMAND_LONG")
                     if m.command == M.MAV_CMD_SET_MESSAGE_INTERVAL}
        for msg_id in (M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                       M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
            assert 0 < intervals[msg_id] <= 20_000, (msg_id, intervals)  # >= 50 Hz
        await clock.sleep(4.0)  # 1 s of wall time
        s = v.state()
        assert abs(clock.now_ns() - s.timestamp_ns) < 0.2e9 * clock.factor
        hist = [v.state_at(s.timestamp_ns - int(k * 1e7)) for k in range(100)]
        assert all(h is not None for h in hist[:90])
        times = sorted({h.timestamp_ns for h in hist if h is not None})
        assert times == sorted(times)


async def test_offboard_first_setpoint_is_here_then_speed_limited_steps() -> None:
    """PX4's local frame is the EKF origin, home is 0.35 m S / 0.45 m E of it (emulator default):
    the driver's NED (home) frame and the setpoints on the wire differ by that offset."""
    cfg = {"offboard_max_speed_mps": 2.0, "offboard_rate_hz": 20.0}
    async with flying_pair(3.0, record=True, vehicle=cfg) as (emu, v, clock):
        off = emu.config.home_in_origin_ned_m
        await v.arm()
        await v.takeoff(4.0)
        await wait_for(lambda: v.state().flight_mode == FlightMode.HOLD and v.state().in_air, 20.0,
                       "hover")
        here = v.state()
        goal = Setpoint(here.position_ned_m[0] + 6.0, here.position_ned_m[1], -4.0,
                        wrap_deg(here.yaw_deg + 170.0))
        n_before = len(emu.received("SET_POSITION_TARGET_LOCAL_NED"))
        await v.start_offboard(goal)
        for _ in range(60):
            await v.set_setpoint(goal)
            await clock.sleep(0.05)
        timed = [(t.sim_s, t.msg) for t in list(emu.traffic) if t.direction == "in"
                 and t.msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED"][n_before:]
        sps = [m for _, m in timed]
        first = sps[0]
        assert first.type_mask == 0x09F8  # position + yaw, as MAVSDK sent to PX4
        assert math.dist((first.x, first.y, first.z),
                         (here.position_ned_m[0] + off[0], here.position_ned_m[1] + off[1],
                          here.position_ned_m[2] + off[2])) < 0.3  # here, never (0, 0, 0)
        assert abs(wrap_deg(math.degrees(first.yaw) - here.yaw_deg)) < 2.0
        xs = [m.x for m in sps]
        t0, x0 = timed[0][0], xs[0]
        for (t, _), x in zip(timed, xs):  # 2 m/s (clock = emulator time) + one late tick
            assert x - x0 <= 2.0 * (t - t0) + 2.0 * 0.5, (t - t0, x - x0)
        distinct = len(set(np.round(xs, 4)))
        wall_s = 60 * 0.05 / 3.0
        assert distinct / wall_s >= 10.0  # fresh steps at >= 10 Hz, not only MAVSDK's re-sends
        # yaw went up by 170 deg through +180 (the short way is +170, not -190)
        yaws = [wrap_deg(math.degrees(m.yaw) - here.yaw_deg) for m in sps]
        assert min(yaws) > -1.0 and max(yaws) > 100.0
        await wait_for(lambda: math.dist(v.state().position_ned_m, goal.position_ned_m) < 0.5,
                       10.0, "reach the offboard goal")
        truth = emu.snapshot().true_position_ned_m
        assert math.dist(truth, goal.position_ned_m) < 0.8  # home frame on both sides
        await v.stop_offboard()
        assert v.state().flight_mode == FlightMode.HOLD


async def test_offboard_needs_a_fresh_valid_local_position() -> None:
    async with flying_pair(4.0, vehicle={"position_max_age_s": 0.5}) as (emu, v, clock):
        await v.arm()
        s = v.state()
        emu.inject_link_loss(1.0)  # no position sample for a while
        await asyncio.sleep(0.3)  # 1.2 s of clock time > position_max_age_s
        with pytest.raises(VehicleError, match="valid local position") as info:
            await v.start_offboard(Setpoint(*s.position_ned_m, s.yaw_deg))
        assert info.value.result == "NO_VALID_POSITION"
        assert emu.snapshot().mode == FlightMode.HOLD  # nothing was sent


async def test_errors_are_typed_with_call_and_result_and_params_and_gripper() -> None:
    async with flying_pair(4.0) as (emu, v, clock):
        emu.deny_next_command("COMPONENT_ARM_DISARM")
        with pytest.raises(VehicleError) as info:
            await v.arm()
        assert (info.value.result, info.value.origin) == ("COMMAND_DENIED", "arm()")
        assert any(e.kind == "refused" for e in v.events())
        await v.arm()
        assert await v.get_param("SYS_AUTOSTART") == 10040  # int param, bytewise on the wire
        assert await v.get_param("COM_OF_LOSS_T") == pytest.approx(1.0)
        with pytest.raises(VehicleError) as info:
            await v.get_param("NO_SUCH_PARAM")
        assert info.value.origin == "get_param()" and info.value.params == "NO_SUCH_PARAM"
        await v.release()
        assert emu.snapshot().gripper == "release"
        await v.grab()
        assert emu.snapshot().gripper == "grab"
        with pytest.raises(VehicleError, match="altitude_m"):
            await v.takeoff(float("nan"))


async def test_gripper_waits_for_px4s_in_progress_then_accepted() -> None:
    """PX4 v1.16 answers DO_GRIPPER IN_PROGRESS, then ACCEPTED PD_GRIPPER_TO (1 s) later
    (probed: ``python benchmarks/probe_mavsdk_plugins.py --url udpin://0.0.0.0:14541 --tap``);
    MAVSDK 4.1's Gripper plugin returns UNKNOWN at the first ack and calls back again at the
    second (it crashed the probe), so ``grab()`` / ``release()`` send DO_GRIPPER through
    MavlinkDirect, which waits for the final ack: they return once the gripper is done. A
    refusal is a VehicleError with the MAV_RESULT."""
    async with flying_pair(4.0) as (emu, v, clock):
        assert emu.snapshot().gripper == "grab"  # PX4 grabs at boot
        t0 = clock.now_ns()
        await v.release()
        assert emu.snapshot().gripper == "release"
        assert (clock.now_ns() - t0) / 1e9 > 0.8  # waited for the final ACCEPTED
        t0 = clock.now_ns()
        await v.release()  # already released: ACCEPTED at once
        assert (clock.now_ns() - t0) / 1e9 < 0.8
        emu.deny_next_command("DO_GRIPPER")
        with pytest.raises(VehicleError) as info:
            await v.grab()
        assert (info.value.result, info.value.origin) == ("COMMAND_DENIED", "grab()")
        await v.grab()
        assert emu.snapshot().gripper == "grab"
        assert [e.data["action"] for e in v.events() if e.kind == "gripper"] == ["release", "release", "grab"]


async def test_driver_commands_the_autopilots_own_system_id() -> None:
    """A real aircraft may have another MAV_SYS_ID than 1 (a second PX4 SITL instance has 2:
    ``PX4_INSTANCE=1``): the driver's own COMMAND_LONGs (the ground-truth stream request,
    DO_GRIPPER) name the connected autopilot's system id in their fields, without relying on
    MAVSDK 4.1's MavlinkDirect, which puts the bound system's id on the wire whatever the fields
    say (checked against PX4 instance 1 and here)."""
    async with flying_pair(4.0, record=True, emulator={"sysid": 2}) as (emu, v, clock):
        assert v.session.system_id == 2
        truth = v.ground_truth()
        assert truth is not None
        await wait_for(truth.available, 5.0, "HIL_STATE_QUATERNION from system 2")
        await v.release()
        assert emu.snapshot().gripper == "release"
        assert await v.get_param("MAV_SYS_ID") == 2
        commands = emu.received("COMMAND_LONG")
        assert commands and {m.target_system for m in commands} == {2}


async def test_status_texts_become_events_and_link_loss_is_reported() -> None:
    async with flying_pair(4.0, vehicle={"link_timeout_s": 1.0}) as (emu, v, clock):
        await v.arm()
        await wait_for(lambda: any("Armed by external command" in e.text for e in v.events()
                                   if e.kind == "status"), 2.0, "status text event")
        emu.inject_link_loss(1.0)
        await wait_for(lambda: not v.state().link_ok, 2.0, "link_ok False")
        await wait_for(lambda: v.state().link_ok, 4.0, "link back")
        await wait_for(lambda: [e.data.get("ok") for e in v.events() if e.kind == "link"][-1],
                       1.0, "link regained event")
        kinds = [e.data.get("ok") for e in v.events() if e.kind == "link"]
        assert kinds[-2:] == [False, True]


# ---------------------------------------------------------------------------------------------
# the watchdog thread on its own
# ---------------------------------------------------------------------------------------------
def test_watchdog_fires_once_when_not_fed_even_with_the_caller_blocked() -> None:
    fired: list[tuple[float, str]] = []
    wd = OffboardWatchdog(0.2, lambda age: fired.append((age, threading.current_thread().name)))
    wd.start()
    try:
        wd.arm()
        for _ in range(10):  # fed: nothing happens
            time.sleep(0.05)
            wd.feed()
        assert not fired
        t0 = time.monotonic()
        time.sleep(0.5)  # the caller hangs (this thread blocks, the watchdog's does not)
        assert len(fired) == 1 and fired[0][1] == "offboard-watchdog"
        assert 0.2 <= fired[0][0] < 0.35 and time.monotonic() - t0 >= 0.2
        time.sleep(0.3)
        assert len(fired) == 1  # one shot until re-armed
        wd.arm()
        wd.disarm()
        time.sleep(0.3)
        assert len(fired) == 1  # disarmed on purpose: silent
    finally:
        wd.stop()
    with pytest.raises(ValueError):
        OffboardWatchdog(0.0, lambda age: None)


async def test_watchdog_holds_a_blocked_loop_through_mavsdk() -> None:
    """The mission's event loop blocks (time.sleep inside it): MAVSDK keeps re-sending the last
    setpoint, so only the watchdog thread can command HOLD."""
    async with flying_pair(3.0, vehicle={"watchdog_timeout_s": 0.3}) as (emu, v, clock):
        await v.arm()
        await v.takeoff(3.0)
        await wait_for(lambda: v.state().flight_mode == FlightMode.HOLD and v.state().in_air, 20.0,
                       "hover")
        s = v.state()
        sp = Setpoint(*s.position_ned_m, s.yaw_deg)
        await v.start_offboard(sp)
        for _ in range(10):
            await v.set_setpoint(sp)
            await asyncio.sleep(0.05)
        n_sp = emu.snapshot()
        assert n_sp.mode == FlightMode.OFFBOARD
        t0 = time.monotonic()
        time.sleep(1.0)  # blocked loop
        assert emu.snapshot().mode == FlightMode.HOLD  # switched while we were blocked
        assert time.monotonic() - t0 >= 0.3
        await asyncio.sleep(0.1)
        with pytest.raises(VehicleError, match="watchdog"):
            await v.set_setpoint(sp)
        assert any(e.kind == "watchdog" for e in v.events())
