"""Fuzz target: a whole simulated mission flown under hostile telemetry.

The assembled envelope reads its vehicle through :class:`HostileTelemetry` (the mission, its
telemetry watch and the envelope all see the corrupted states); a side task corrupts the
telemetry in bursts (NaN, a jump of kilometres, stamps going backwards, a stale or replayed
state, the link and the position flagged invalid) at random times of the flight.

Property: the flight ends (no unexpected error), every command that left the envelope was
inside it (:func:`check_sent`), the TRUE trajectory has no envelope violation and the run
ends safe (the evaluator's ``ended_safe``).
"""

from __future__ import annotations

import asyncio
import random
from typing import Any

from eaglemission.lab.campaign.sim import run_simulation
from fuzz_common import FuzzCrash
from fuzz_telemetry import HostileTelemetry, check_sent

from eaglemission.config import MissionFile
from eaglemission.safety.envelope import SafeVehicle

TARGET = "mission"
BURSTS = ("nan", "inf", "jump", "backwards", "stale", "replay", "invalid", "nan_velocity",
          "nan_attitude")


def check_mission(cfg: MissionFile, seed: int) -> str:
    """Fly ``cfg`` with seeded telemetry bursts; the final state, or :class:`FuzzCrash`."""
    rng = random.Random(seed)
    parts: dict[str, Any] = {}

    def prepare(asm: Any) -> None:
        hostile = HostileTelemetry(asm.driver)
        # the flight's envelope reads the vehicle through it: the mission, its telemetry watch
        # and the envelope all see the bursts
        asm.vehicle = SafeVehicle(hostile, asm.config.safety, clock=asm.clock)
        parts.update(hostile=hostile, safe=asm.vehicle)

    async def bursts(_mission: Any) -> None:
        hostile = parts["hostile"]
        while True:
            await asyncio.sleep(rng.uniform(0.5, 6.0))
            hostile.corruption = rng.choice(BURSTS)
            await asyncio.sleep(rng.choice((0.02, 0.1, 0.3, 1.0)))
            hostile.corruption = "none"

    try:
        out = run_simulation(cfg, prepare=prepare, side_tasks=(bursts,), keep_log=False)
    except Exception as exc:
        raise FuzzCrash(TARGET, f"the flight raised {type(exc).__name__}: {exc}", seed) from exc
    check_sent(parts["safe"], parts["hostile"].sent, seed)
    ev = out.evaluation
    if ev.violations:
        raise FuzzCrash(TARGET, f"envelope violations on the true trajectory: "
                        f"{ev.violations[:3]}", seed)
    if not ev.ended_safe:
        raise FuzzCrash(TARGET, f"did not end safe: {out.final_state} ({out.reason})", seed)
    return f"{out.final_state}: {out.reason}"
