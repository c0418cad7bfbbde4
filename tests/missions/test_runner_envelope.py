"""The runner always commands through the safety envelope, whatever vehicle it is given."""

from __future__ import annotations

import asyncio

from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicle
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.log import MissionLog
from eaglemission.missions.runner import MissionRunner

from eaglemission.clock import ManualClock
from eaglemission.safety.envelope import SafeVehicle


def make_runner(vehicle, sitl_config) -> MissionRunner:
    async def build() -> MissionRunner:
        clock = ManualClock()
        return MissionRunner(
            sitl_config, ApproachConfig(), vehicle=vehicle, cameras={},
            models={c: sitl_config.cameras.wide.to_model(c) for c in ("wide", "narrow")},
            tools={}, clock=clock,
            mission_log=MissionLog(None, now_ns=clock.now_ns))

    return asyncio.run(build())


def test_a_raw_vehicle_is_wrapped_in_the_envelope(sitl_config) -> None:
    raw = SimulatedVehicle(clock=ManualClock())
    runner = make_runner(raw, sitl_config)
    assert isinstance(runner.vehicle, SafeVehicle)
    assert runner.vehicle is not raw


def test_an_envelope_is_not_wrapped_twice(sitl_config) -> None:
    clock = ManualClock()
    safe = SafeVehicle(SimulatedVehicle(clock=clock), sitl_config.safety, clock=clock)
    assert make_runner(safe, sitl_config).vehicle is safe
