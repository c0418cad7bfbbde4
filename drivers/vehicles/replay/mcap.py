"""What a recorded flight's vehicle told the mission (``/vehicle/*`` of an MCAP recording,
written by :class:`~eaglemission.recording.vehicle_tap.VehicleTap`), answered again by time for the
``replay`` vehicle.

An answer recorded at flight time ``t`` after ``k`` completed commands is visible from
``t`` on, and at ``t`` itself only once the replay has completed ``k`` commands too: at one
instant the state before ``arm()`` and the one after it come back in the order the flight saw
them. ``state()`` is the newest visible answer; ``state_at(t)`` the recorded answer to the
same lookup, else an interpolation of the visible states (a replay that asks at other times:
another config, a real-time recording); ``events()`` the visible events; a command or
parameter call gets its recorded result (an error is raised again, same type and text).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

from eaglemission.errors import (
    ConfigError,
    ModeChangedExternally,
    SafetyViolation,
    VehicleError,
)
from eaglemission.recording.folder import state_from_json
from eaglemission.recording.mcap_reader import messages
from eaglemission.recording.vehicle_tap import (
    TOPIC_COMMAND,
    TOPIC_EVENT,
    TOPIC_PARAM,
    TOPIC_STATE,
    TOPIC_STATE_AT,
)
from eaglemission.telemetry.history import TelemetryHistory
from eaglemission.types import VehicleEvent, VehicleState

_ERRORS: dict[str, type[VehicleError]] = {
    "VehicleError": VehicleError, "SafetyViolation": SafetyViolation,
    "ModeChangedExternally": ModeChangedExternally}


def _state(d: dict[str, Any] | None) -> VehicleState | None:
    return None if d is None else state_from_json(json.dumps(d))


def recorded_error(err: dict[str, Any]) -> Exception:
    """The recorded error again: same type (a driver error, or TimeoutError) and text."""
    text = str(err.get("text", ""))
    if err.get("type") == "TimeoutError":
        return TimeoutError(text)
    cls = _ERRORS.get(str(err.get("type")), VehicleError)
    exc = cls(str(err.get("result", "")), str(err.get("origin", "")))
    exc.args = (text,)
    return exc


Stamp = tuple[int, int]
"""(flight time ns, commands completed) of a recorded answer."""


class McapVehicleLog:
    """The ``/vehicle/*`` channels of one recording (see the module docstring)."""

    def __init__(self, path: Path, *, where: str = "vehicle.params.path") -> None:
        self.states: list[tuple[Stamp, VehicleState]] = []
        self.lookups: dict[int, list[tuple[Stamp, VehicleState | None]]] = defaultdict(list)
        self.events: list[tuple[Stamp, VehicleEvent]] = []
        self.command_errors: dict[tuple[str, int], dict[str, Any]] = {}
        self.params: dict[str, list[dict[str, Any]]] = defaultdict(list)
        self.end_ns = 0
        try:
            for topic, msg in messages(path):
                self.end_ns = max(self.end_ns, int(msg.log_time))
                if topic.startswith("/vehicle/"):
                    self._add(topic, json.loads(msg.data))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{where}: cannot read {str(path)!r} as a recording: {exc}") from exc
        if not self.states:
            raise ConfigError(f"{where}: {str(path)!r} holds no vehicle telemetry "
                              f"({TOPIC_STATE}): record the flight with this version's "
                              "`eaglemission run --record FILE.mcap`")
        self.history = TelemetryHistory(span_s=max(2.0, (self.end_ns - self.states[0][1]
                                                         .timestamp_ns) * 1e-9 + 2.0))
        self._next_state = 0
        self._next_event = 0
        self.current = self.states[0][1]
        self.done = 0
        """Commands the replay completed."""
        self._calls: dict[str, int] = defaultdict(int)

    def _add(self, topic: str, m: dict[str, Any]) -> None:
        stamp = (int(m["t_ns"]), int(m["commands"]))
        if topic == TOPIC_STATE:
            st = _state(m["state"])
            assert st is not None
            self.states.append((stamp, st))
        elif topic == TOPIC_STATE_AT:
            self.lookups[int(m["query_ns"])].append((stamp, _state(m["state"])))
        elif topic == TOPIC_EVENT:
            e = m["event"]
            self.events.append((stamp, VehicleEvent(int(e["timestamp_ns"]), str(e["kind"]),
                                                    str(e["text"]), dict(e["data"]))))
        elif topic == TOPIC_COMMAND and not m["ok"]:
            self.command_errors[(str(m["name"]), int(m["index"]))] = m["error"]
        elif topic == TOPIC_PARAM:
            self.params[f"{m['call']}:{json.dumps(m['args'])}"].append(m)

    def visible(self, stamp: Stamp, now_ns: int) -> bool:
        return stamp[0] < now_ns or (stamp[0] == now_ns and stamp[1] <= self.done)

    def advance(self, now_ns: int) -> None:
        """Take in every state visible at ``now_ns``."""
        while (self._next_state < len(self.states)
               and self.visible(self.states[self._next_state][0], now_ns)):
            st = self.states[self._next_state][1]
            self.history.append(st)
            self.current = st
            self._next_state += 1

    def state_at(self, timestamp_ns: int, now_ns: int) -> VehicleState | None:
        self.advance(now_ns)
        seen = [st for stamp, st in self.lookups.get(int(timestamp_ns), ())
                if self.visible(stamp, now_ns)]
        if seen:
            return seen[-1]
        return self.history.state_at(timestamp_ns)

    def events_until(self, now_ns: int) -> list[VehicleEvent]:
        while (self._next_event < len(self.events)
               and self.visible(self.events[self._next_event][0], now_ns)):
            self._next_event += 1
        return [ev for _, ev in self.events[:self._next_event]]

    def command(self, name: str) -> None:
        """One command completed: raises its recorded error, if it failed."""
        index = self._calls[name]
        self._calls[name] += 1
        self.done += 1
        err = self.command_errors.get((name, index))
        if err is not None:
            raise recorded_error(err)

    def param(self, call: str, *args: Any) -> float:
        """A parameter read or set, answered as recorded (the first recorded answer to the
        same call; a call never recorded: PARAM_UNKNOWN)."""
        answers = self.params.get(f"{call}:{json.dumps(list(args))}")
        if not answers:
            raise VehicleError("PARAM_UNKNOWN", f"{call}()", args,
                               "not in the recording (replay)")
        a = answers[0]
        if not a["ok"]:
            raise recorded_error(a["error"])
        value = a.get("value")
        return float(value) if isinstance(value, int | float) else math.nan
