"""The Vehicle contract suite on the MAVSDK driver: against the PX4-like MAVLink emulator over
MAVSDK's ``raw://`` (in-process bytes, fast), and against a real PX4 SITL (SIH or jMAVSim)
through the ``px4_sitl`` fixture (tests/conftest.py): a fresh PX4 per test when
``EAGLEMISSION_PX4_BUILD`` is set, the running one at ``EAGLEMISSION_PX4_URL`` (e.g.
``udpin://0.0.0.0:14540``) otherwise; skipped when neither is set.

Time: the emulator runs ``SPEEDUP`` times faster than the wall clock and the backend's clock
(:class:`ScaledClock`) runs at the same rate, so the suite's durations (sized for a real PX4)
are emulator seconds. MAVSDK's own timers stay in wall time (heartbeat timeouts, command
retries); the driver's watchdog is a wall-time thread (its contract timeout is
``watchdog_wall_s * SPEEDUP`` clock seconds).
"""

from __future__ import annotations

import asyncio
import os
import socket
import time
from collections.abc import AsyncIterator
from typing import Any

import pytest
from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle
from eaglemission.lab.vehicles.emulator.emulator import EmulatorConfig, Px4Emulator
from emulator_support import ScaledClock
from udp_relay import UdpRelay
from vehicle_contract import (
    BackendBase,
    VehicleContract,
    start_offboard_here,
    stream,
    stream_until,
    take_off,
)

from eaglemission.errors import ModeChangedExternally
from eaglemission.names import ENV_PX4_URL
from eaglemission.types import FlightMode

pytestmark = pytest.mark.machine  # a PX4 SITL's fixed ports when set (tests/conftest.py)

SPEEDUP = 4.0
WATCHDOG_WALL_S = 0.3


class EmulatorBackend(BackendBase):
    """MAVSDK driver <-> raw:// <-> PX4-like emulator (same process, no sockets)."""

    hooks = frozenset({"link_loss", "pilot_mode_change", "block_event_loop"})

    def __init__(self, emulator: Px4Emulator, vehicle: MavsdkVehicle, clock: ScaledClock) -> None:
        super().__init__(vehicle, clock)
        self.name = "mavsdk-emulator"
        self.emulator = emulator
        self.scaled = clock
        self.watchdog_timeout_s = vehicle.watchdog_timeout_s * clock.factor
        # HEARTBEAT (and so the armed state and the mode) is sent at 1 Hz of emulator time
        # only, as PX4 does (up to 1 clock second late); MAVSDK's in_air comes from
        # EXTENDED_SYS_STATE at the requested rate.
        self.report_lag_s = 1.5

    async def link_loss(self, duration_s: float) -> None:
        # Command timeouts are wall time (the driver's command_timeout_s, MAVSDK's ~2 s of
        # retries): the loss must outlast detection + timeout for an unanswered command to fail
        # inside it, whatever the speed-up.
        self.emulator.inject_link_loss(max(duration_s / self.scaled.factor, 3.0))

    async def pilot_mode_change(self, mode: FlightMode) -> None:
        self.emulator.pilot_take_control(mode)

    async def block_event_loop(self, seconds: float) -> None:
        time.sleep(seconds / self.scaled.factor)  # nothing on this loop runs meanwhile


def make_emulator_backend(seed: int = 5) -> EmulatorBackend:
    clock = ScaledClock(SPEEDUP)
    # RTL_RETURN_ALT 10 m as in the recorded scenario (c) (PX4's default 60 m only makes the
    # return test slower)
    emu = Px4Emulator(EmulatorConfig(speedup=SPEEDUP, seed=seed,
                                     params={"RTL_RETURN_ALT": 10.0}))
    vehicle = MavsdkVehicle(
        MavsdkVehicle.Config(url="raw://", connect_timeout_s=10.0, command_timeout_s=1.5,
                             watchdog_timeout_s=WATCHDOG_WALL_S, link_timeout_s=1.5),
        clock=clock, mavlink_peer=emu)
    return EmulatorBackend(emu, vehicle, clock)


@pytest.fixture
async def vehicle_backend() -> AsyncIterator[EmulatorBackend]:
    backend = make_emulator_backend()
    backend.emulator.start()
    try:
        await backend.vehicle.connect()
        yield backend
    finally:
        await backend.vehicle.close()
        backend.emulator.stop()


class MavsdkLinkTests:
    """What the MAVSDK driver adds to the contract on a cut link."""

    async def test_link_loss_while_offboard_is_reported_as_a_failover(
            self, vehicle_backend: EmulatorBackend | Px4Backend) -> None:
        """PX4 fails over after COM_OF_LOSS_T without setpoints and, when they return, goes
        back to OFFBOARD without a mode report (recorded i): the driver must say so."""
        b = vehicle_backend
        await take_off(b)
        sp = await start_offboard_here(b)
        await stream(b, sp, 1.0)
        assert not [e for e in b.vehicle.events() if e.kind == "failover"]
        await b.link_loss(3.0)
        # the setpoints go on, into the void, then again to PX4
        await stream_until(b, sp, lambda st: not st.link_ok, 10.0, "link lost")
        try:
            await stream_until(b, sp, lambda st: st.link_ok, 60.0, "link regained")
            await stream(b, sp, 2.0)
            back_in_offboard = True
        except ModeChangedExternally:
            # a HEARTBEAT sent in the failover mode reached us before our first setpoint
            # reached PX4: the driver ends its control (it cannot know PX4 will come back)
            back_in_offboard = False
        ev = [e for e in b.vehicle.events() if e.kind == "failover"]
        assert ev, "no failover event after a 3 s link loss while offboard"
        loss_timeout_s = ev[0].data["offboard_loss_timeout_s"]
        assert ev[0].data["gap_s"] > loss_timeout_s
        if back_in_offboard:  # PX4 went straight back to OFFBOARD (recorded i)
            assert b.vehicle.state().flight_mode == FlightMode.OFFBOARD
        else:
            events = list(b.vehicle.events())
            ended = [i for i, e in enumerate(events) if e.kind == "mode"
                     and e.text.startswith("offboard ended")]
            assert ended, "ModeChangedExternally raised without an 'offboard ended' event"
            # the gap is told by the first message after it, the HEARTBEAT included, so the
            # mission sees the failover no later than the mode that ended its control
            first_failover = next(i for i, e in enumerate(events) if e.kind == "failover")
            assert first_failover < ended[0], events[-6:]
            # Setpoints already on their way when the driver stopped may still bring PX4 back
            # to OFFBOARD (recorded i); with none after them it fails over again COM_OF_LOSS_T
            # later, shown at the next HEARTBEAT.
            await b.wait(lambda st: st.flight_mode == FlightMode.POSCTL,
                         loss_timeout_s + 2 * b.report_lag_s + 1.0,
                         "Position again once the driver stopped its setpoints")
            with pytest.raises(ModeChangedExternally):
                await b.vehicle.set_setpoint(sp)  # the driver does not take control back


class TestMavsdkEmulatorContract(VehicleContract, MavsdkLinkTests):
    pass


# ---------------------------------------------------------------------------------------------
# Real PX4 SITL (run elsewhere: no PX4 build can be installed on the CI machines)
# ---------------------------------------------------------------------------------------------
PX4_GCS_LINK = "udpin:0.0.0.0:14550"
"""PX4 SITL's GCS link (QGroundControl's port): PX4 sends to 127.0.0.1:14550 from UDP 18570."""

_PX4_MODES = {FlightMode.HOLD: (4, 3), FlightMode.POSCTL: (3, 0),
              FlightMode.RETURN_TO_LAUNCH: (4, 5), FlightMode.LAND: (4, 6)}
"""DO_SET_MODE (main, sub) a ground station sends (recorded h2: 176 (129, 4, 3) for Hold)."""


def gcs_set_mode(mode: FlightMode, url: str = PX4_GCS_LINK, timeout_s: float = 5.0) -> list[int]:
    """A second ground station (pymavlink, sysid 255 / compid 190, as in recorded h1-h3) on
    PX4's GCS link commands ``mode``; returns the COMMAND_ACK results PX4 sent on that link
    (PX4 v1.16 answers DO_SET_MODE twice). Blocking: run it in a thread."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    main, sub = _PX4_MODES[mode]
    conn = mavutil.mavlink_connection(url, source_system=255, source_component=190)
    try:
        deadline = time.monotonic() + timeout_s
        if conn.wait_heartbeat(timeout=timeout_s) is None:  # learn PX4's address
            raise AssertionError(f"no PX4 HEARTBEAT on the GCS link {url} within {timeout_s:g} s")
        conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID,
                                0, 0, mavutil.mavlink.MAV_STATE_ACTIVE)
        conn.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 0,
                                   129, main, sub, 0, 0, 0, 0)
        results: list[int] = []
        while time.monotonic() < deadline and len(results) < 2:
            msg = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.2)
            if msg is not None and msg.command == mavutil.mavlink.MAV_CMD_DO_SET_MODE:
                results.append(int(msg.result))
        if not results:
            raise AssertionError(f"PX4 did not acknowledge DO_SET_MODE {mode.value} on {url}")
        return results
    finally:
        conn.close()


class Px4Backend(BackendBase):
    """A real PX4 v1.16 SITL: wall time, 1 Hz heartbeats (modes show up to ~1 s late); a pilot's
    mode change comes from a second ground station on PX4's GCS link (UDP 14550); the link is
    cut by a loopback relay between PX4 and the driver (:class:`udp_relay.UdpRelay`)."""

    hooks = frozenset({"block_event_loop", "pilot_mode_change", "link_loss"})
    report_lag_s = 1.5

    def __init__(self, vehicle: MavsdkVehicle, clock: ScaledClock, relay: UdpRelay) -> None:
        super().__init__(vehicle, clock)
        self.name = "mavsdk-px4"
        self.watchdog_timeout_s = vehicle.watchdog_timeout_s
        self.relay = relay

    async def link_loss(self, duration_s: float) -> None:
        self.relay.cut(duration_s)

    async def block_event_loop(self, seconds: float) -> None:
        time.sleep(seconds)

    async def pilot_mode_change(self, mode: FlightMode) -> None:
        results = await asyncio.to_thread(gcs_set_mode, mode)
        assert results[-1] == 0, f"PX4 refused {mode.value} from the GCS link: results {results}"


@pytest.fixture
async def px4_backend(px4_sitl: Any) -> AsyncIterator[Px4Backend]:
    """The MAVSDK driver on the test's own PX4 (``px4_sitl``: tests/conftest.py)."""
    url = px4_sitl.url
    scheme, _, where = url.partition("://")
    if scheme != "udpin" or not where.rpartition(":")[2].isdigit():
        pytest.skip(f"{ENV_PX4_URL}={url}: the PX4 suite relays a udpin:// link (e.g. "
                    "udpin://0.0.0.0:14540) to cut it")
    relay = UdpRelay(px4_port=int(where.rpartition(":")[2]), driver_port=_free_udp_port())
    clock = ScaledClock(1.0)
    vehicle = MavsdkVehicle(MavsdkVehicle.Config(
        url=f"udpin://127.0.0.1:{relay.driver_addr[1]}", connect_timeout_s=30.0,
        watchdog_timeout_s=0.5,
        ground_truth_altitude="ned_z" if px4_sitl.sim == "jmavsim" else "amsl",
        ground_truth_horizontal="velocity" if px4_sitl.sim == "jmavsim" else "latlon"),
        clock=clock)
    try:
        await vehicle.connect()
    except BaseException:
        relay.close()
        raise
    try:
        yield Px4Backend(vehicle, clock, relay)
    finally:
        try:  # leave the SITL on the ground AND disarmed for the next test: armed in LAND,
            # PX4 would auto-disarm it 2 s after "Landing detected", during the next takeoff
            s = vehicle.state()
            if s.armed and s.in_air and s.flight_mode not in (FlightMode.LAND,
                                                               FlightMode.RETURN_TO_LAUNCH):
                await vehicle.land()
            if vehicle.state().armed:
                await vehicle.wait_landed_and_disarmed(land_timeout_s=90.0)
            if vehicle.state().flight_mode == FlightMode.OFFBOARD:
                # disarmed, PX4 shows OFFBOARD again (the last mode the user selected) and
                # is not armable without a setpoint stream: leave it in Hold
                await vehicle.hold()
        finally:
            await vehicle.close()
            relay.close()


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.mark.px4
class TestMavsdkPx4SitlContract(VehicleContract, MavsdkLinkTests):
    @pytest.fixture
    def vehicle_backend(self, px4_backend: Px4Backend) -> Px4Backend:
        return px4_backend
