"""Ground truth: where the vehicle really is (simulators only).

Truth is for the fake sensors (a synthetic camera renders the world from the true pose) and the
evaluator (judging a flight against reality). The mission never sees it. A vehicle plugin offers
it with an optional method ``ground_truth() -> GroundTruth | None``: the ``simulated`` vehicle
always; the ``mavsdk`` vehicle when the autopilot streams HIL_STATE_QUATERNION (PX4 SITL/SIH and
the bundled emulator do; a real aircraft has none).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

from eaglemission.types import XYZ, Quat, VehicleState


@runtime_checkable
class GroundTruth(Protocol):
    """The true pose of the vehicle, in NED metres relative to its true start point (the
    world's origin), host-monotonic nanoseconds like every other stamp."""

    description: str
    """Where the truth comes from, for the run header (e.g. "HIL_STATE_QUATERNION")."""

    def available(self) -> bool:
        """True once at least one true sample is known."""
        ...

    def pose_at(self, timestamp_ns: int) -> tuple[XYZ, Quat] | None:
        """(position_ned_m, attitude_q) at a host time, interpolated (None outside the record)."""
        ...

    def trajectory(self) -> Sequence[VehicleState]:
        """Every true state recorded so far, time-ordered (``in_air``/``armed`` filled)."""
        ...
