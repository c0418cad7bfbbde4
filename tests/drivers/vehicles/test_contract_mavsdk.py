"""The Vehicle contract suite on the MAVSDK driver: against the PX4-like MAVLink emulator over
MAVSDK's ``raw://`` (in-process bytes, fast), and against a real PX4 SITL when
``EAGLEMISSION_PX4_URL`` is set (e.g. ``udpin://0.0.0.0:14540`` with PX4's SIH simulator,
``PX4_SIM_MODEL=sihsim_quadx``; skipped otherwise).

Time: the emulator runs ``SPEEDUP`` times faster than the wall clock and the backend's clock
(:class:`ScaledClock`) runs at the same rate, so the suite's durations (sized for a real PX4)
are emulator seconds. MAVSDK's own timers stay in wall time (heartbeat timeouts, command
retries); the driver's watchdog is a wall-time thread (its contract timeout is
``watchdog_wall_s * SPEEDUP`` clock seconds).
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import AsyncIterator

import pytest
from eaglemission.drivers.vehicles.mavlink_emulator import EmulatorConfig, Px4Emulator
from eaglemission.drivers.vehicles.mavsdk_vehicle import MavsdkVehicle

from eaglemission.names import ENV_PX4_URL
from eaglemission.types import FlightMode

try:  # tests/ is not a package: the contract module sits next to this file
    from contract import BackendBase, VehicleContract
    from emulator_support import ScaledClock
except ImportError:  # pragma: no cover - when tests/ becomes a package
    from .contract import BackendBase, VehicleContract  # type: ignore[no-redef]
    from .emulator_support import ScaledClock  # type: ignore[no-redef]

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
        # HEARTBEAT (and so the armed state and the mode) is sent on change by the emulator,
        # but MAVSDK's in_air comes from EXTENDED_SYS_STATE at the requested rate.
        self.report_lag_s = 0.5

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
                                     stream_rates_hz={"HEARTBEAT": 2.0},
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


class TestMavsdkEmulatorContract(VehicleContract):
    pass


# ---------------------------------------------------------------------------------------------
# Real PX4 SITL (run elsewhere: no PX4 build can be installed on the CI machines)
# ---------------------------------------------------------------------------------------------
class Px4Backend(BackendBase):
    """A real PX4 v1.16 SITL: wall time, 1 Hz heartbeats (modes show up to ~1 s late),
    no fault-injection hooks (a real autopilot cannot be told to lose its link)."""

    hooks = frozenset({"block_event_loop"})
    report_lag_s = 1.5

    def __init__(self, vehicle: MavsdkVehicle, clock: ScaledClock) -> None:
        super().__init__(vehicle, clock)
        self.name = "mavsdk-px4"
        self.watchdog_timeout_s = vehicle.watchdog_timeout_s

    async def block_event_loop(self, seconds: float) -> None:
        time.sleep(seconds)


@pytest.fixture
async def px4_backend() -> AsyncIterator[Px4Backend]:
    url = os.environ.get(ENV_PX4_URL)
    if not url:
        pytest.skip(f"set {ENV_PX4_URL} (e.g. udpin://0.0.0.0:14540) to run against a real PX4 SITL")
    clock = ScaledClock(1.0)
    vehicle = MavsdkVehicle(MavsdkVehicle.Config(url=url, connect_timeout_s=30.0,
                                                 watchdog_timeout_s=0.5), clock=clock)
    await vehicle.connect()
    try:
        yield Px4Backend(vehicle, clock)
    finally:
        try:  # leave the SITL on the ground for the next test
            s = vehicle.state()
            if s.armed and s.in_air:
                await vehicle.land()
                deadline = time.monotonic() + 60.0
                while vehicle.state().in_air and time.monotonic() < deadline:
                    await asyncio.sleep(0.5)
        finally:
            await vehicle.close()


@pytest.mark.px4
class TestMavsdkPx4SitlContract(VehicleContract):
    @pytest.fixture
    def vehicle_backend(self, px4_backend: Px4Backend) -> Px4Backend:
        return px4_backend
