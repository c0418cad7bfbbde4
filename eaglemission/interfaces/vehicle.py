"""Vehicle role (entry-point group ``eaglemission.vehicles``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

from eaglemission.types import (
    GeoPoint,
    MissionProgress,
    Setpoint,
    VehicleEvent,
    VehicleState,
    Waypoint,
)


@runtime_checkable
class Vehicle(Protocol):
    """An autopilot, real or simulated. Every command is async, bounded by the driver's
    configured timeouts, and raises :class:`~eaglemission.errors.VehicleError` (result code +
    origin) on refusal and :class:`~eaglemission.errors.TimeoutError_` when such a wait runs
    out (both :class:`~eaglemission.errors.DriverError`: what a caller catches). ``state()`` is a cheap snapshot of the latest telemetry; ``state_at``
    interpolates the pose at a past host-monotonic time from a ~2 s history (None outside it).

    Construction: ``cls(config=<cls.Config instance>, clock=Clock, **context)``.
    Vehicles are async context managers; ``close`` is idempotent.
    """

    async def connect(self) -> None: ...

    async def close(self) -> None: ...

    def state(self) -> VehicleState: ...

    def state_at(self, timestamp_ns: int) -> VehicleState | None: ...

    def events(self) -> Sequence[VehicleEvent]: ...

    async def arm(self) -> None: ...

    async def disarm(self) -> None: ...

    async def takeoff(self, altitude_m: float) -> None: ...

    async def goto(self, target: GeoPoint, yaw_deg: float) -> None: ...

    async def upload_mission(self, waypoints: Sequence[Waypoint]) -> None: ...

    async def start_mission(self) -> None: ...

    def mission_progress(self) -> MissionProgress: ...

    async def start_offboard(self, initial: Setpoint) -> None: ...

    async def set_setpoint(self, setpoint: Setpoint) -> None: ...

    async def stop_offboard(self) -> None: ...

    async def hold(self) -> None: ...

    async def land(self) -> None: ...

    async def return_to_launch(self) -> None: ...

    async def grab(self) -> None: ...

    async def release(self) -> None: ...
