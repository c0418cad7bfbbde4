"""The camera loops: each camera grabbed at the mission's processing rate while the state
needs it, frames queued for perception with the vehicle state at their mid-exposure.

A camera is grabbed only while the state's policy needs it (cruise: wide only, as the paper
does), so a synthetic camera renders lazily; with ``record_all`` both are grabbed whenever
airborne (a recording has both streams). Grabs run in worker threads, bounded.
"""

from __future__ import annotations

import asyncio
import functools
import math
import time
from collections.abc import Callable, Mapping

from eaglemission.missions.log import MissionLog

from eaglemission import errors
from eaglemission.clock import Clock, VirtualTimeLoop, run_blocking
from eaglemission.interfaces import Camera, Vehicle
from eaglemission.types import Frame, VehicleState

QueuedFrame = tuple[Frame, float, VehicleState | None]
"""(frame, host wall time of its mid-exposure, vehicle state at that time)."""


def _is_virtual() -> bool:
    try:
        return isinstance(asyncio.get_running_loop(), VirtualTimeLoop)
    except RuntimeError:
        return False


class CameraPump:
    """One loop per camera feeding a bounded queue (the oldest frame is dropped when
    perception is behind)."""

    def __init__(self, cameras: Mapping[str, Camera], vehicle: Vehicle, clock: Clock,
                 log: MissionLog, *, rate_hz: float, needed: Callable[[], set[str]],
                 recording: Callable[[], bool],
                 on_frame: Callable[[Frame], None] | None = None) -> None:
        self.cameras, self.vehicle, self.clock, self.log = cameras, vehicle, clock, log
        self.rate_hz = rate_hz
        self.needed, self.recording, self.on_frame = needed, recording, on_frame
        self.frames: asyncio.Queue[QueuedFrame] = asyncio.Queue(maxsize=4)
        self.last_frame_ns: dict[str, int] = {}
        self.needed_since_ns: dict[str, int] = {}
        self.stopping = False

    def failed(self, now_ns: int, after_s: float) -> bool:
        """A needed camera has delivered no frame for ``after_s``."""
        for c in self.needed():
            since = max(self.last_frame_ns.get(c, 0), self.needed_since_ns.get(c, now_ns))
            if (now_ns - since) * 1e-9 > after_s:
                return True
        return False

    def streaming(self) -> bool:
        return all(c in self.last_frame_ns for c in self.cameras)

    async def run(self, cam_id: str) -> None:
        cam = self.cameras[cam_id]
        rate = min(self.rate_hz, float(getattr(cam, "frame_rate_hz", math.inf)))
        period_ns = int(1e9 / rate)
        next_ns = self.clock.now_ns()
        grab_timeout_s = max(0.5, 3.0 / rate)
        while not self.stopping:
            if cam_id not in self.needed() and not self.recording():
                self.needed_since_ns.pop(cam_id, None)
                await self.clock.sleep(period_ns * 1e-9)
                next_ns = self.clock.now_ns()
                continue
            self.needed_since_ns.setdefault(cam_id, self.clock.now_ns())
            await self.clock.sleep(max(0.0, (next_ns - self.clock.now_ns()) * 1e-9))
            next_ns = max(next_ns + period_ns, self.clock.now_ns())
            try:
                frame = await asyncio.wait_for(asyncio.shield(run_blocking(
                    functools.partial(cam.grab, timeout_s=grab_timeout_s))),
                    timeout=grab_timeout_s + 1.0)
            except errors.EndOfStream:
                self.log.write("event", source=cam_id, text="end of stream")
                return
            except (errors.CameraError, TimeoutError) as exc:
                self.log.write("event", source=cam_id, text=f"grab failed: {exc}")
                continue
            # wall-clock time of the frame's mid-exposure: arrival minus the frame's age then
            # (virtual time stands still while the camera renders: age 0)
            age_s = 0.0 if _is_virtual() else max(
                0.0, (self.clock.now_ns() - frame.timestamp_ns) * 1e-9)
            wall = time.perf_counter() - age_s
            self.last_frame_ns[cam_id] = self.clock.now_ns()
            if self.on_frame is not None:
                self.on_frame(frame)
            if cam_id not in self.needed():
                continue  # recorded only: perception does not need this camera now
            item = (frame, wall, self.vehicle.state_at(frame.timestamp_ns))
            try:
                self.frames.put_nowait(item)
            except asyncio.QueueFull:
                self.frames.get_nowait()  # drop the oldest: perception is behind
                self.frames.put_nowait(item)
