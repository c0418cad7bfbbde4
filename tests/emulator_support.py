"""Helpers shared by the MAVSDK-driver and emulator tests (not a test module)."""

from __future__ import annotations

import asyncio
import functools
import os
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle
from eaglemission.lab.vehicles.emulator.emulator import EmulatorConfig, Px4Emulator


class ScaledClock:
    """Host monotonic time running ``factor`` times faster, anchored at creation; callable
    from any thread (the MAVSDK driver stamps telemetry with it in MAVSDK's thread). With the
    emulator's ``speedup`` equal to ``factor``, clock seconds are emulator seconds."""

    def __init__(self, factor: float) -> None:
        self.factor = float(factor)
        self._t0 = time.monotonic_ns()

    def now_ns(self) -> int:
        return self._t0 + int((time.monotonic_ns() - self._t0) * self.factor)

    async def sleep(self, duration_s: float) -> None:
        await asyncio.sleep(max(0.0, duration_s) / self.factor)


@asynccontextmanager
async def flying_pair(speedup: float = 4.0, *, record: bool = False, emulator: dict[str, Any] | None = None,
                      vehicle: dict[str, Any] | None = None
                      ) -> AsyncIterator[tuple[Px4Emulator, MavsdkVehicle, ScaledClock]]:
    """An emulator and a connected MAVSDK driver over ``raw://``, on a common scaled clock."""
    clock = ScaledClock(speedup)
    emu = Px4Emulator(EmulatorConfig(speedup=speedup, **(emulator or {})), record=record)
    v = MavsdkVehicle(MavsdkVehicle.Config(url="raw://", **(vehicle or {})), clock=clock,
                      mavlink_peer=emu)
    emu.start()
    try:
        await v.connect()
        # as the recorded clients did (they waited for health, >= 1 s): PX4 has heard the
        # client's GCS HEARTBEAT (it sends STATUSTEXT only then) and sent its first 1 Hz
        # streams (MISSION_CURRENT) before the first command
        await wait_for(lambda: emu.statustext_link_live(), 5.0, "a GCS HEARTBEAT from MAVSDK")
        if record:
            await wait_for(lambda: any(t.direction == "out" and t.msg.get_type() == "MISSION_CURRENT"
                                       for t in list(emu.traffic)), 5.0, "first MISSION_CURRENT")
        yield emu, v, clock
    finally:
        await v.close()
        emu.stop()


async def wait_for(predicate: Any, timeout_s: float, what: str, poll_s: float = 0.02) -> Any:
    """Wall-time bounded poll (raises AssertionError naming ``what``)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not reached within {timeout_s:g} s (wall)")
        await asyncio.sleep(poll_s)


@functools.lru_cache(maxsize=8)
def read_tlog(path: str) -> tuple[tuple[float, Any], ...]:
    """(epoch seconds at the relay, message) for every packet of a tlog (cached)."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(path, dialect="development")
    out = []
    while (msg := mlog.recv_match()) is not None:
        if msg.get_type() != "BAD_DATA":
            out.append((msg._timestamp, msg))
    return tuple(out)


def scenario(tlogs: Path, name: str) -> tuple[tuple[tuple[float, Any], ...], tuple[tuple[float, Any], ...], float]:
    """(PX4 -> client, client -> PX4, t0) of a recorded scenario; times relative to t0."""
    px4 = read_tlog(str(tlogs / f"scenario_{name}_px4_to_client.tlog"))
    client = read_tlog(str(tlogs / f"scenario_{name}_client_to_px4.tlog"))
    t0 = min(px4[0][0], client[0][0])
    return (tuple((t - t0, m) for t, m in px4), tuple((t - t0, m) for t, m in client), t0)
