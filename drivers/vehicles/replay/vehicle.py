"""``replay`` vehicle plugin: a recorded run's telemetry stands in for the vehicle, open loop.

The replay deployment (docs/recording.md): ``replay`` cameras and this vehicle play one
recording (written by ``eaglemission run --record DIR``) through the same detector ->
estimator -> state machine. The recorded flight goes on whatever the mission commands:
every command is accepted and logged as an event ("open loop"), and ``state()`` is the
recorded telemetry at the flight clock's time. In virtual time the flight's clock starts at
the recording's first stamp (:meth:`ReplayVehicle.start_time_ns`), so stamps are the
recording's; in real time they are shifted by one offset shared with the replay cameras.
After the last record the vehicle reports its last state with the link down. ``armable`` is
reported true throughout (the recorded flight arms anyway: the gate means nothing open loop).

An MCAP recording (``path: flight.mcap``, ``run --record``) holds what the flight's vehicle
answered the mission (:mod:`.replay_mcap`): states, lookups, events, command and parameter
results are answered as recorded, by time, and nothing is added (no open-loop events), so a
replay that asks the same questions gets the same answers (``eaglemission replay``); only
``armable`` stays true while the recorded vehicle is armed (a replay whose preflight ends later
than the flight's would wait for a vehicle that armed already).
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from eaglemission.drivers.vehicles.replay.mcap import McapVehicleLog
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.clock import Clock, MonotonicClock
from eaglemission.errors import ConfigError, VehicleError
from eaglemission.flight.context import REPLAY_EPOCH_NS, SharedContext
from eaglemission.recording.folder import read_telemetry, recording_start_ns
from eaglemission.recording.mcap_reader import start_ns as mcap_start_ns
from eaglemission.telemetry.history import TelemetryHistory
from eaglemission.types import (
    GeoPoint,
    MissionProgress,
    Setpoint,
    VehicleEvent,
    VehicleState,
    Waypoint,
)

EVENT_REPLAY = "replay"  # a command the open-loop replay accepted and ignored; end of recording


class ReplayVehicleConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    path: str = Field(description="recorded run folder (its telemetry.jsonl) or MCAP "
                                  "recording (FILE.mcap)")


class ReplayVehicle:
    """Recorded telemetry as a vehicle (see the module docstring)."""

    Config = ReplayVehicleConfig
    description = "Replays a recorded run's telemetry, open loop (commands accepted, not flown)"
    simulated = True

    @classmethod
    def start_time_ns(cls, config: ReplayVehicleConfig) -> int | None:
        """Where a virtual-time flight's clock starts: the recording's first stamp."""
        return _start_ns(Path(config.path).expanduser())

    @classmethod
    def config_problems(cls, mission: Any, path: str) -> list[str]:
        run = Path(str(mission.vehicle.params.get("path", ""))).expanduser()
        if run.suffix.lower() == ".mcap":
            return [] if run.is_file() else [f"{path}.params.path: {str(run)!r} does not exist"]
        if not (run / "telemetry.jsonl").exists():
            return [f"{path}.params.path: {str(run)!r} holds no recorded run (telemetry.jsonl):"
                    " record one with `eaglemission run --record DIR`"]
        return []

    def __init__(self, config: ReplayVehicleConfig | None = None, *, clock: Clock | None = None,
                 shared: SharedContext | None = None, **_context: Any) -> None:
        if config is None:
            raise ConfigError("vehicle.params.path: the replay vehicle needs a recorded run")
        self.config = config
        self.clock: Clock = clock or MonotonicClock()
        self._run = Path(config.path).expanduser()
        start = _start_ns(self._run)
        if start is None:
            raise ConfigError(f"vehicle.params.path: {str(self._run)!r} holds no recorded run")

        def epoch() -> int:
            return int(self.clock.now_ns()) - start

        self._epoch_ns = epoch() if shared is None else shared.get_or_create(REPLAY_EPOCH_NS,
                                                                             epoch)
        self._history: TelemetryHistory | None = None
        self._first: VehicleState | None = None
        self._last: VehicleState | None = None
        self._events: list[VehicleEvent] = []
        self._lock = threading.Lock()
        self._ended = False
        self._connected = False
        self._mcap: McapVehicleLog | None = None

    # -- lifetime --------------------------------------------------------------------------
    async def connect(self) -> None:
        if self._connected:
            return
        if self._run.suffix.lower() == ".mcap":
            self._mcap = McapVehicleLog(self._run)
            self._history = self._mcap.history
            self._first, self._last = self._mcap.states[0][1], self._mcap.states[-1][1]
            self._connected = True
            return
        try:
            states = read_telemetry(self._run)
        except (OSError, ValueError) as exc:
            raise VehicleError("CONNECTION_ERROR", "connect()", str(self._run), str(exc)) from exc
        if not states:
            raise VehicleError("CONNECTION_ERROR", "connect()", str(self._run),
                               "the recording holds no telemetry")
        span_s = (states[-1].timestamp_ns - states[0].timestamp_ns) * 1e-9 + 2.0
        h = TelemetryHistory(span_s=span_s, max_extrapolation_s=0.05)
        for st in states:
            h.append(self._shift(st))
        self._history, self._first, self._last = h, self._shift(states[0]), self._shift(states[-1])
        self._connected = True

    async def close(self) -> None:
        self._connected = False

    async def __aenter__(self) -> ReplayVehicle:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    def summary(self) -> str:
        return f"recording {self._run}, open loop"

    def __getattr__(self, name: str) -> Any:
        mcap: McapVehicleLog | None = self.__dict__.get("_mcap")
        if name in ("get_param", "set_param") and mcap is not None:
            async def call(*args: Any) -> float:
                return mcap.param(name, *args)

            return call
        raise AttributeError(name)

    # -- telemetry -------------------------------------------------------------------------
    def _shift(self, st: VehicleState) -> VehicleState:
        if not self._epoch_ns:
            return st
        return dataclasses.replace(st, timestamp_ns=st.timestamp_ns + self._epoch_ns)

    def _require(self, origin: str) -> TelemetryHistory:
        if self._history is None:
            raise VehicleError("NO_SYSTEM", origin, None, "call `await vehicle.connect()` first")
        return self._history

    def state(self) -> VehicleState:
        h = self._require("state()")
        assert self._first is not None and self._last is not None
        now = int(self.clock.now_ns())
        if self._mcap is not None:
            rec = now - self._epoch_ns
            self._mcap.advance(rec)
            cur = self._shift(self._mcap.current)
            if cur.armed and not cur.armable:  # armed already: see _open_loop
                cur = dataclasses.replace(cur, armable=True)
            return cur if rec <= self._mcap.end_ns else dataclasses.replace(cur, link_ok=False)
        if now < self._first.timestamp_ns:
            return _open_loop(self._first)
        if now > self._last.timestamp_ns:
            with self._lock:
                if not self._ended:
                    self._ended = True
                    self._events.append(VehicleEvent(now, EVENT_REPLAY, "end of the recording",
                                                     {}))
            return dataclasses.replace(_open_loop(self._last), link_ok=False)
        st = h.state_at(now)
        return _open_loop(st if st is not None else self._last)

    def state_at(self, timestamp_ns: int) -> VehicleState | None:
        h = self._require("state_at()")
        if self._mcap is not None:
            found = self._mcap.state_at(timestamp_ns - self._epoch_ns,
                                        int(self.clock.now_ns()) - self._epoch_ns)
            return None if found is None else self._shift(found)
        return h.state_at(timestamp_ns)

    def events(self) -> Sequence[VehicleEvent]:
        if self._mcap is not None:
            return tuple(self._mcap.events_until(int(self.clock.now_ns()) - self._epoch_ns))
        with self._lock:
            return tuple(self._events)

    def mission_progress(self) -> MissionProgress:
        return MissionProgress(0, 0)

    # -- commands: accepted, not flown -------------------------------------------------------
    def _ignored(self, origin: str) -> None:
        self._require(origin)
        if self._mcap is not None:  # the recorded result; nothing added
            self._mcap.command(origin.removesuffix("()"))
            return
        with self._lock:
            self._events.append(VehicleEvent(int(self.clock.now_ns()), EVENT_REPLAY,
                                             f"{origin}: accepted (open loop: the recorded "
                                             "flight goes on)", {"command": origin}))

    async def arm(self) -> None:
        self._ignored("arm()")

    async def disarm(self) -> None:
        self._ignored("disarm()")

    async def takeoff(self, altitude_m: float) -> None:
        self._ignored("takeoff()")

    async def goto(self, target: GeoPoint, yaw_deg: float) -> None:
        self._ignored("goto()")

    async def upload_mission(self, waypoints: Sequence[Waypoint]) -> None:
        self._ignored("upload_mission()")

    async def start_mission(self) -> None:
        self._ignored("start_mission()")

    async def start_offboard(self, initial: Setpoint) -> None:
        self._ignored("start_offboard()")

    async def set_setpoint(self, setpoint: Setpoint) -> None:
        self._require("set_setpoint()")  # streamed at 20 Hz: not logged one by one
        if self._mcap is not None:
            self._mcap.command("set_setpoint")

    async def stop_offboard(self) -> None:
        self._ignored("stop_offboard()")

    async def hold(self) -> None:
        self._ignored("hold()")

    async def land(self) -> None:
        self._ignored("land()")

    async def return_to_launch(self) -> None:
        self._ignored("return_to_launch()")

    async def grab(self) -> None:
        self._ignored("grab()")

    async def release(self) -> None:
        self._ignored("release()")


def _start_ns(path: Path) -> int | None:
    if path.suffix.lower() == ".mcap":
        return mcap_start_ns(path) if path.is_file() else None
    return recording_start_ns(path)


def _open_loop(st: VehicleState) -> VehicleState:
    """A recorded state as the replayed mission sees it: ``armable`` stays true (an autopilot
    reports "not armable" once armed; the recorded flight arms whatever the replayed mission's
    preflight decides, so that gate is meaningless open loop)."""
    return st if st.armable else dataclasses.replace(st, armable=True)
