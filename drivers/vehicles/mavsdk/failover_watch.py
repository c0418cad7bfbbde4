"""A failover the autopilot made while the link was down, told by the gap it leaves.

PX4 (recorded i) declares offboard loss COM_OF_LOSS_T after the last setpoint, switches to
Position and sinks; when the link returns MAVSDK's next setpoint puts it straight back in
OFFBOARD and the client never sees a mode change. A silence in the telemetry (every stream)
longer than COM_OF_LOSS_T while offboard means the setpoints did not arrive either
(docs/vehicles.md). The gap is told at the first message after it, whichever stream it is on, so
the event comes before a HEARTBEAT's failover mode ends our offboard control."""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from typing import Any

from eaglemission.drivers.vehicles.events import EVENT_FAILOVER

from eaglemission.errors import VehicleError

log = logging.getLogger(__name__)

PX4_DEFAULT_OFFBOARD_LOSS_S = 1.0  # COM_OF_LOSS_T


def failover_text(gap_s: float, timeout_s: float) -> str:
    return (f"no telemetry for {gap_s:.1f} s while offboard (more than COM_OF_LOSS_T "
            f"{timeout_s:g} s): the autopilot failed over while the link was down")


def failover_data(gap_s: float, timeout_s: float) -> dict[str, object]:
    return {"gap_s": round(gap_s, 3), "offboard_loss_timeout_s": timeout_s}


class FailoverWatch:
    """Fed every gap between two telemetry samples (any stream); ``offboard()`` says whether an
    offboard session was active. Emits one ``failover`` event per gap over ``timeout_s``."""

    def __init__(self, offboard: Callable[[], bool],
                 event: Callable[[str, str, dict[str, Any]], None],
                 timeout_s: float = PX4_DEFAULT_OFFBOARD_LOSS_S) -> None:
        self.offboard, self.event, self.timeout_s = offboard, event, float(timeout_s)
        self._was_offboard = False  # at the previous sample

    async def read_timeout(self, get_param: Callable[[str], Awaitable[float]]) -> None:
        """COM_OF_LOSS_T from the autopilot; PX4's default when it cannot be read."""
        try:
            self.timeout_s = float(await get_param("COM_OF_LOSS_T"))
        except VehicleError as exc:  # not PX4, or no answer
            log.info("COM_OF_LOSS_T not read (%s): assuming %g s", exc, self.timeout_s)

    def on_gap(self, gap_s: float) -> None:
        was, self._was_offboard = self._was_offboard, self.offboard()
        if gap_s > self.timeout_s and was:
            self.event(EVENT_FAILOVER, failover_text(gap_s, self.timeout_s),
                       failover_data(gap_s, self.timeout_s))
