"""The Vehicle contract suite on the simulated vehicle (ManualClock: instant in wall time)."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest
from eaglemission.lab.vehicles.multicopter.dynamics import DynamicsParams
from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle
from eaglemission.lab.world.synthetic import SyntheticWorldConfig
from vehicle_contract import BackendBase, VehicleContract

from eaglemission.clock import ManualClock
from eaglemission.config import SafetyConfig
from eaglemission.interfaces import Vehicle
from eaglemission.types import FlightMode


class SimulatedBackend(BackendBase):
    """The simulated vehicle (optionally wrapped in the safety envelope) on a ManualClock.

    ``clock.sleep`` advances the clock, so a test that waits 30 s runs in milliseconds; a
    "blocked event loop" is time passing with nothing running (the clock jumps).
    """

    hooks = frozenset({"link_loss", "pilot_mode_change", "block_event_loop"})
    report_lag_s = 0.0

    def __init__(self, name: str, sim: SimulatedVehicle, clock: ManualClock, vehicle: Vehicle) -> None:
        super().__init__(vehicle, clock)
        self.name = name
        self.sim = sim
        self.manual_clock = clock
        self.watchdog_timeout_s = sim.config.offboard_loss_timeout_s

    async def link_loss(self, duration_s: float) -> None:
        self.sim.inject_link_loss(duration_s)

    async def pilot_mode_change(self, mode: FlightMode) -> None:
        self.sim.pilot_take_control(mode)

    async def block_event_loop(self, seconds: float) -> None:
        self.manual_clock.advance(seconds)  # time passes, no task runs


def make_backend(variant: str, seed: int = 7) -> SimulatedBackend:
    clock = ManualClock()
    simulation = SyntheticWorldConfig(seed=seed, wind_ne_mps=(3.0, -2.0) if variant == "windy" else (0.0, 0.0))
    dyn = DynamicsParams(wind_gust_std_mps=1.0) if variant == "windy" else DynamicsParams()
    sim = SimulatedVehicle(SimulatedVehicle.Config(dynamics=dyn), clock=clock, simulation=simulation)
    vehicle: Vehicle = sim
    if variant == "safe":
        from eaglemission.safety.envelope import SafeVehicle

        vehicle = SafeVehicle(sim, SafetyConfig(), clock=clock)
    return SimulatedBackend(f"simulated-{variant}", sim, clock, vehicle)


@pytest.fixture(params=["calm", "windy", "safe"])
async def vehicle_backend(request: pytest.FixtureRequest) -> AsyncIterator[SimulatedBackend]:
    backend = make_backend(request.param)
    await backend.vehicle.connect()
    yield backend
    await backend.vehicle.close()


class TestSimulatedContract(VehicleContract):
    pass
