"""The camera loops: each camera grabbed at the mission's processing rate while the state
needs it, frames queued for perception with the vehicle state at their mid-exposure.

A camera is grabbed only while the state's policy needs it (cruise: wide only, as the paper
does), so a synthetic camera renders lazily; with ``record_all`` both are grabbed whenever
airborne (a recording has both streams). Grabs run in worker threads, bounded.

Every frame is counted per camera (:class:`FrameCounts`): ``grabbed`` = ``processed`` +
``skipped`` + ``dropped``.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import math
import time
from collections.abc import Callable, Iterator, Mapping

from eaglemission.missions.log import MissionLog

from eaglemission import errors
from eaglemission.clock import Clock, VirtualTimeLoop, run_blocking
from eaglemission.interfaces import Camera, Vehicle
from eaglemission.types import Frame, VehicleState

QueuedFrame = tuple[Frame, float, VehicleState | None]
"""(frame, host wall time of its mid-exposure, vehicle state at that time)."""

COUNTS = ("grabbed", "processed", "skipped", "dropped")
MAX_FRAME_SKEW_S = 1.0
"""A frame stamped further than this from the mission clock is refused (a camera clock jump)."""


def frame_problem(frame: Frame, width_px: int, height_px: int, last_seq: int | None,
                  now_ns: int) -> tuple[str, str] | None:
    """(what, text) when a grabbed frame cannot be used: wrong size (a truncated transfer), a
    sequence number not after the last one (a frozen driver re-delivering), a stamp far from
    the clock (a jump of the camera's clock). None: usable."""
    h, w = frame.image.shape[:2]
    if (w, h) != (width_px, height_px):
        return "frame_rejected", f"frame of {w}x{h} px, expected {width_px}x{height_px}"
    if last_seq is not None and frame.seq <= last_seq:
        return "frame_repeated", f"frame {frame.seq} again (last {last_seq})"
    skew_s = (frame.timestamp_ns - now_ns) * 1e-9
    if abs(skew_s) > MAX_FRAME_SKEW_S:
        return "frame_stamp", f"frame stamped {skew_s:+.2f} s from the clock"
    return None


class FrameCounts:
    """Per camera: frames ``grabbed`` (taken from the camera, plus the frames a camera's
    sequence numbers show it delivered between two paced grabs), ``skipped`` (not meant for
    perception: those in-between frames the processing rate let pass, frames grabbed only for
    a recording while the state does not use the camera, frames arriving after the mission's
    final state), ``dropped`` (meant to be processed and not: perception was behind and the
    queue dropped its oldest, or the flight ended first) and ``processed``."""

    def __init__(self, cameras: list[str]) -> None:
        self.counts = {c: dict.fromkeys(COUNTS, 0) for c in cameras}
        self._last_seq: dict[str, int] = {}

    def grabbed(self, frame: Frame) -> None:
        c = self.counts[frame.camera_id]
        last = self._last_seq.get(frame.camera_id)
        gap = frame.seq - last - 1 if last is not None and frame.seq > last else 0
        c["grabbed"] += 1 + gap
        c["skipped"] += gap
        self._last_seq[frame.camera_id] = frame.seq

    def idle(self, camera_id: str) -> None:
        """The pump stopped taking this camera's frames: the next gap is no skip."""
        self._last_seq.pop(camera_id, None)

    def add(self, camera_id: str, what: str, n: int = 1) -> None:
        self.counts[camera_id][what] += n

    def as_dict(self) -> dict[str, dict[str, int]]:
        return {c: dict(v) for c, v in self.counts.items()}

    @contextlib.contextmanager
    def dropped_on_error(self, camera_id: str) -> Iterator[None]:
        """A frame in perception: dropped if perception raises (or is cancelled)."""
        try:
            yield
        except BaseException:
            self.add(camera_id, "dropped")
            raise


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
        self.counts = FrameCounts(list(cameras))
        self.last_frame_ns: dict[str, int] = {}
        self.last_seq: dict[str, int] = {}
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
                self.counts.idle(cam_id)
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
                self.log.write("fault_detected", what="grab_failed", camera=cam_id,
                               text=str(exc), response="no frame; camera watch running")
                continue
            problem = frame_problem(frame, cam.model.width_px, cam.model.height_px,
                                    self.last_seq.get(cam_id), self.clock.now_ns())
            if problem is not None:
                self.counts.add(cam_id, "grabbed")
                self.counts.add(cam_id, "dropped")
                self.log.write("fault_detected", what=problem[0], camera=cam_id,
                               text=problem[1], response="frame dropped")
                continue
            self.last_seq[cam_id] = frame.seq
            # wall-clock time of the frame's mid-exposure: arrival minus the frame's age then
            # (virtual time stands still while the camera renders: age 0)
            age_s = 0.0 if _is_virtual() else max(
                0.0, (self.clock.now_ns() - frame.timestamp_ns) * 1e-9)
            wall = time.perf_counter() - age_s
            self.last_frame_ns[cam_id] = self.clock.now_ns()
            self.counts.grabbed(frame)
            if self.on_frame is not None:
                self.on_frame(frame)
            if cam_id not in self.needed():
                self.counts.add(cam_id, "skipped")
                continue  # recorded only: perception does not need this camera now
            item = (frame, wall, self.vehicle.state_at(frame.timestamp_ns))
            try:
                self.frames.put_nowait(item)
            except asyncio.QueueFull:
                old = self.frames.get_nowait()  # drop the oldest: perception is behind
                self.counts.add(old[0].camera_id, "dropped")
                self.frames.put_nowait(item)

    async def take(self, *, final: Callable[[], bool]) -> QueuedFrame | None:
        """The next frame for perception (None: none within 0.5 s, or the mission is in its
        final state: the frame is skipped)."""
        try:
            item = await asyncio.wait_for(self.frames.get(), timeout=0.5)
        except TimeoutError:
            return None
        if final():
            self.counts.add(item[0].camera_id, "skipped")
            return None
        return item

    def final_counts(self, processed: Mapping[str, int], *, final: bool
                     ) -> dict[str, dict[str, int]]:
        """The counts at the end: frames still queued are skipped after the final state, else
        dropped; ``processed``: the mission's own count."""
        while not self.frames.empty():
            frame = self.frames.get_nowait()[0]
            self.counts.add(frame.camera_id, "skipped" if final else "dropped")
        for c, n in processed.items():
            self.counts.counts[c]["processed"] = n
        return self.counts.as_dict()
