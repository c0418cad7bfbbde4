"""Which injected faults are active now: written by the injector on the event loop, read by the
fault wrappers (cameras, detectors, estimators) from worker threads."""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

from eaglemission.lab.faults.config import FaultSpec

PERMANENT = frozenset({"camera_device_loss", "camera_clock_jump", "battery_drain"})
"""Kinds that last to the end of the flight, whatever ``duration_s`` says."""

FRAME_FAULTS = frozenset({"corrupted_frame", "truncated_frame"})
"""Kinds that spoil frames: each hits every frame grabbed in its window and at least the first
frame grabbed after it starts (a window shorter than the grab period would otherwise miss)."""


@dataclass(frozen=True)
class ActiveFault:
    spec: FaultSpec
    start_ns: int
    end_ns: float  # inf for a permanent fault

    def covers(self, now_ns: int) -> bool:
        return self.start_ns <= now_ns < self.end_ns


class ActiveFaults:
    """The faults injected so far, with their time windows (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._faults: list[ActiveFault] = []
        self._frames_hit: set[tuple[int, str]] = set()  # (fault index, camera)

    def activate(self, spec: FaultSpec, now_ns: int) -> ActiveFault:
        end = math.inf if spec.kind in PERMANENT else now_ns + spec.duration_s * 1e9
        fault = ActiveFault(spec, now_ns, end)
        with self._lock:
            self._faults.append(fault)
        return fault

    def active(self, kind: str, now_ns: int, camera_id: str | None = None) -> FaultSpec | None:
        """The active fault of ``kind`` (for ``camera_id``, when camera faults name one)."""
        with self._lock:
            for f in self._faults:
                if f.spec.kind != kind or not f.covers(now_ns):
                    continue
                if camera_id is not None and f.spec.camera not in ("both", camera_id):
                    continue
                return f.spec
        return None

    def frame_fault(self, kind: str, now_ns: int, camera_id: str) -> FaultSpec | None:
        """The fault of ``kind`` (one of :data:`FRAME_FAULTS`) that spoils ``camera_id``'s frame
        grabbed now: one whose window covers now, or one started that has not yet spoiled a
        frame of this camera."""
        if kind not in FRAME_FAULTS:
            raise ValueError(f"{kind!r} is not a frame fault ({', '.join(sorted(FRAME_FAULTS))})")
        with self._lock:
            for i, f in enumerate(self._faults):
                if f.spec.kind != kind or f.start_ns > now_ns:
                    continue
                if f.spec.camera not in ("both", camera_id):
                    continue
                first = (i, camera_id) not in self._frames_hit
                if f.covers(now_ns) or first:
                    self._frames_hit.add((i, camera_id))
                    return f.spec
        return None
