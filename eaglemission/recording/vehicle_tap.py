"""What the mission got from its vehicle, for a recording that replays exactly.

A :class:`VehicleTap` sits between the vehicle driver and the safety envelope of a recorded
flight (``run --record FILE.mcap``) and hands every answer to the recorder, as JSON, on
these channels (docs/recording.md):

* ``/vehicle/state``: every new answer of ``state()`` (a new telemetry sample, or the same
  sample changed by a command: armed, mode);
* ``/vehicle/state_at``: every ``state_at(t)`` lookup (a frame's mid-exposure pose) and its
  answer;
* ``/vehicle/event``: every vehicle event, when the mission first saw it;
* ``/vehicle/command``: every command and its result (failed streamed setpoints too; the
  accepted ones are the ``/log/setpoint`` records);
* ``/vehicle/param``: every autopilot parameter read or set, and its result.

Each message carries ``n`` (its number), ``t_ns`` (the flight clock when the mission asked)
and ``commands`` (the commands completed by then): at one instant, a state observed after a command is told apart
from the one before it. The ``replay`` vehicle answers from these channels
(``drivers/vehicles/replay/mcap.py``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

from eaglemission.clock import Clock
from eaglemission.errors import DriverError
from eaglemission.types import GeoPoint, Setpoint, VehicleEvent, VehicleState, Waypoint

TOPIC_STATE = "/vehicle/state"
TOPIC_STATE_AT = "/vehicle/state_at"
TOPIC_EVENT = "/vehicle/event"
TOPIC_COMMAND = "/vehicle/command"
TOPIC_PARAM = "/vehicle/param"
VEHICLE_TOPICS = (TOPIC_STATE, TOPIC_STATE_AT, TOPIC_EVENT, TOPIC_COMMAND, TOPIC_PARAM)

Sink = Callable[[str, int, dict[str, Any]], None]
"""``sink(topic, t_ns, message)``: the recorder's :meth:`~McapRecorder.message`."""


_STATE_FIELDS = tuple(f.name for f in dataclasses.fields(VehicleState))
_GEO_FIELDS = tuple(f.name for f in dataclasses.fields(GeoPoint))


def state_dict(st: VehicleState) -> dict[str, Any]:
    """A state as ``recording.state_from_json`` reads it back (no deep copies: the tap runs
    on every new sample)."""
    d = {k: getattr(st, k) for k in _STATE_FIELDS}
    for k in ("geodetic", "home"):
        g = d[k]
        if g is not None:
            d[k] = {f: getattr(g, f) for f in _GEO_FIELDS}
    d["flight_mode"] = str(st.flight_mode.value)
    if not math.isfinite(st.battery_voltage_v):
        d["battery_voltage_v"] = None
    return d


def error_json(exc: BaseException) -> dict[str, Any]:
    """A driver error as the replay raises it again."""
    if isinstance(exc, DriverError):
        return {"type": type(exc).__name__, "result": exc.result, "origin": exc.origin,
                "text": str(exc)}
    return {"type": type(exc).__name__, "result": "", "origin": "", "text": str(exc)}


class VehicleTap:
    """A vehicle that forwards everything to ``inner`` and records its answers (see the module
    docstring). Messages wait (at most ``max_pending``) until :meth:`bind` gives the sink."""

    def __init__(self, inner: Any, clock: Clock, *, max_pending: int = 100_000) -> None:
        self._inner = inner
        self.clock = clock
        self._sink: Sink | None = None
        self._pending: list[tuple[str, int, dict[str, Any]]] = []
        self._max_pending = max_pending
        self._last_state: VehicleState | None = None
        self._events_seen = 0
        self.commands = 0
        self._n = 0
        """Messages so far (each message's ``n``: the order the mission asked in)."""
        self._calls: Counter[str] = Counter()

    @property
    def inner(self) -> Any:
        return self._inner

    def bind(self, sink: Sink | None) -> None:
        """Send the waiting messages and every later one to ``sink`` (None: stop)."""
        self._sink = sink
        if sink is not None:
            pending, self._pending = self._pending, []
            for item in pending:
                sink(*item)

    def _emit(self, topic: str, fields: dict[str, Any]) -> None:
        t_ns = int(self.clock.now_ns())
        msg = {"n": self._n, "t_ns": t_ns, "commands": self.commands, **fields}
        self._n += 1
        if self._sink is not None:
            self._sink(topic, t_ns, msg)
        elif len(self._pending) < self._max_pending:
            self._pending.append((topic, t_ns, msg))

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._inner, name)
        if name in ("get_param", "set_param"):
            return self._param_call(name, value)
        return value

    # -- telemetry -------------------------------------------------------------------------
    def state(self) -> VehicleState:
        st: VehicleState = self._inner.state()
        if st != self._last_state:
            self._last_state = st
            self._emit(TOPIC_STATE, {"state": state_dict(st)})
        return st

    def state_at(self, timestamp_ns: int) -> VehicleState | None:
        st: VehicleState | None = self._inner.state_at(timestamp_ns)
        self._emit(TOPIC_STATE_AT, {"query_ns": int(timestamp_ns),
                                    "state": None if st is None else state_dict(st)})
        return st

    def events(self) -> Sequence[VehicleEvent]:
        evs: Sequence[VehicleEvent] = self._inner.events()
        for ev in list(evs)[self._events_seen:]:
            self._emit(TOPIC_EVENT, {"event": {"timestamp_ns": ev.timestamp_ns, "kind": ev.kind,
                                               "text": ev.text, "data": _plain(ev.data)}})
        self._events_seen = max(self._events_seen, len(evs))
        return evs

    # -- commands ----------------------------------------------------------------------------
    async def _command(self, name: str, *args: Any) -> None:
        index = self._calls[name]
        self._calls[name] += 1
        try:
            await getattr(self._inner, name)(*args)
        except Exception as exc:
            self.commands += 1
            self._emit(TOPIC_COMMAND, {"name": name, "index": index, "ok": False,
                                       "error": error_json(exc)})
            raise
        self.commands += 1
        if name != "set_setpoint":
            self._emit(TOPIC_COMMAND, {"name": name, "index": index, "ok": True})

    def _param_call(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        async def call(*args: Any) -> Any:
            try:
                value = await fn(*args)
            except Exception as exc:
                self._emit(TOPIC_PARAM, {"call": name, "args": _plain(args), "ok": False,
                                         "error": error_json(exc)})
                raise
            self._emit(TOPIC_PARAM, {"call": name, "args": _plain(args), "ok": True,
                                     "value": _plain(value)})
            return value

        return call

    async def connect(self) -> None:
        await self._inner.connect()

    async def close(self) -> None:
        await self._inner.close()

    async def arm(self) -> None:
        await self._command("arm")

    async def disarm(self) -> None:
        await self._command("disarm")

    async def takeoff(self, altitude_m: float) -> None:
        await self._command("takeoff", altitude_m)

    async def goto(self, target: GeoPoint, yaw_deg: float) -> None:
        await self._command("goto", target, yaw_deg)

    async def upload_mission(self, waypoints: Sequence[Waypoint]) -> None:
        await self._command("upload_mission", waypoints)

    async def start_mission(self) -> None:
        await self._command("start_mission")

    async def start_offboard(self, initial: Setpoint) -> None:
        await self._command("start_offboard", initial)

    async def set_setpoint(self, setpoint: Setpoint) -> None:
        await self._command("set_setpoint", setpoint)

    async def stop_offboard(self) -> None:
        await self._command("stop_offboard")

    async def hold(self) -> None:
        await self._command("hold")

    async def land(self) -> None:
        await self._command("land")

    async def return_to_launch(self) -> None:
        await self._command("return_to_launch")

    async def grab(self) -> None:
        await self._command("grab")

    async def release(self) -> None:
        await self._command("release")


def _plain(value: Any) -> Any:
    """JSON values (tuples as lists, unknown objects as their repr)."""
    return json.loads(json.dumps(value, default=repr))
