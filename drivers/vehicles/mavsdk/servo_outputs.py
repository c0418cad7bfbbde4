"""The autopilot's actuator outputs as it reports them: SERVO_OUTPUT_RAW (PX4 sends it at
10 Hz on the offboard link), each message kept with the host time it arrived."""

from __future__ import annotations

import collections
import json
import threading
from dataclasses import dataclass
from typing import Any

SERVO_CHANNELS = 16


@dataclass(frozen=True, slots=True)
class ServoOutputs:
    """One SERVO_OUTPUT_RAW: the pulse widths (us) of outputs 1-16 of one port."""

    received_ns: int
    """Host time the message arrived."""
    port: int
    pwm_us: tuple[int, ...]
    """Output 1 first; 0 where the autopilot does not send the channel."""


def parse_servo_output_raw(received_ns: int, fields: dict[str, Any]) -> ServoOutputs:
    """A SERVO_OUTPUT_RAW's fields (MAVSDK MavlinkDirect's JSON) as :class:`ServoOutputs`."""
    return ServoOutputs(int(received_ns), int(fields.get("port", 0)),
                        tuple(int(fields.get(f"servo{i}_raw", 0) or 0)
                              for i in range(1, SERVO_CHANNELS + 1)))


class ServoOutputLog:
    """The latest SERVO_OUTPUT_RAW messages (thread-safe: MAVSDK's thread adds)."""

    def __init__(self, keep: int = 256) -> None:
        self._lock = threading.Lock()
        self._items: collections.deque[ServoOutputs] = collections.deque(maxlen=keep)

    def on_message(self, received_ns: int, fields_json: str) -> None:
        try:
            out = parse_servo_output_raw(received_ns, json.loads(fields_json))
        except (ValueError, TypeError):
            return  # a malformed message is dropped; the next one comes in 0.1 s
        with self._lock:
            self._items.append(out)

    def latest(self, port: int = 0) -> ServoOutputs | None:
        with self._lock:
            for item in reversed(self._items):
                if item.port == port:
                    return item
        return None

    def since(self, received_ns: int) -> list[ServoOutputs]:
        with self._lock:
            return [o for o in self._items if o.received_ns >= received_ns]
