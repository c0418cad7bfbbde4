"""Offboard control of the MAVSDK driver, the PX4 way: the first setpoint is the current
position, a timer task streams speed-limited steps towards the latest goal, a watchdog thread
commands HOLD when fresh goals stop (even with the event loop blocked), and a mode change by
anyone else ends our control."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from typing import TYPE_CHECKING, Any

from eaglemission.drivers.vehicles.events import EVENT_MODE, EVENT_WATCHDOG
from eaglemission.drivers.vehicles.mavsdk.support import step_towards
from eaglemission.drivers.vehicles.mavsdk.watchdog import OffboardWatchdog

from eaglemission.errors import ModeChangedExternally, TimeoutError_, VehicleError
from eaglemission.types import FlightMode, Setpoint

if TYPE_CHECKING:  # the vehicle owns its offboard session; imported for the annotations only
    from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle

log = logging.getLogger(__name__)


class OffboardSession:
    """Our offboard control of one :class:`MavsdkVehicle` (its offboard methods call these)."""

    def __init__(self, vehicle: MavsdkVehicle, watchdog_timeout_s: float) -> None:
        self._v = vehicle
        self.watchdog_timeout_s = watchdog_timeout_s
        self._lock = threading.Lock()
        self.active = False
        self._confirmed = False
        self._goal: Setpoint | None = None
        self._cmd: Setpoint | None = None
        self._ended: tuple[str, str] | None = None  # (why, detail)
        self.task: asyncio.Task[None] | None = None
        self.watchdog = OffboardWatchdog(watchdog_timeout_s, self._watchdog_hold)

    def _local_setpoint(self, sp: Setpoint) -> Any:
        hl = self._v.telemetry.home_local() or (0.0, 0.0, 0.0)
        return self._v.mavsdk["PositionNedYaw"](sp.north_m + hl[0], sp.east_m + hl[1],
                                                sp.down_m + hl[2], sp.yaw_deg)

    async def start(self, initial: Setpoint) -> None:
        v = self._v
        c = v.telemetry.cache
        if not isinstance(initial, Setpoint):
            raise VehicleError("NO_SETPOINT_SET", "start_offboard()", None,
                               "give the first goal as a Setpoint")
        if not c.armed:
            raise VehicleError("COMMAND_DENIED", "start_offboard()", (initial,),
                               "the vehicle is not armed: arm (and take off) first")
        age_s = (v.telemetry.now_ns() - c.local_t_ns) * 1e-9
        if not c.local_ok or c.local_ned is None or age_s > v.config.position_max_age_s:
            raise VehicleError("NO_VALID_POSITION", "start_offboard()", (initial,),
                               "PX4 needs a valid local position for offboard "
                               f"(local_position_ok={c.local_ok}, last sample {age_s:.2f} s ago)")
        s = v.state()
        here = Setpoint(*s.position_ned_m, s.yaw_deg)  # never (0, 0, 0): PX4 would fly there
        ob = v.plugins["Offboard"]
        with self._lock:
            self._goal = initial
            self._cmd = here
            self._ended = None
            self._confirmed = c.mode == FlightMode.OFFBOARD
        await v.bounded("start_offboard()", lambda: ob.set_position_ned(self._local_setpoint(here)),
                        params=(initial,))
        self.active = True
        # PX4 confirms OFFBOARD only in its next 1 Hz HEARTBEAT (0.08-0.95 s after the ACCEPTED
        # ack, recorded): the setpoint stream (the timer task, and MAVSDK's own re-sending) keeps
        # running meanwhile, and the watchdog is armed for real once the mode is confirmed.
        # Until then it only holds a backstop deadline past the bounded confirmation wait, so a
        # loop blocked during the wait is still caught.
        confirm_s = v.config.confirm_timeout_s if v.config.confirm_modes else 0.0
        self.watchdog.arm(grace_s=confirm_s + v.config.command_timeout_s)
        if self.task is None or self.task.done():
            self.task = asyncio.get_running_loop().create_task(self._loop(), name="mavsdk-offboard")
        try:
            await v.mode_command("start_offboard()", ob.start, {FlightMode.OFFBOARD},
                                 params=(initial,))
        except TimeoutError_:
            # accepted, but no HEARTBEAT showed OFFBOARD: PX4 may still be in it. Stop MAVSDK's
            # re-sending and ask for HOLD (bounded; refused when not in OFFBOARD: fine).
            self.stop_streaming()
            with contextlib.suppress(Exception):
                await v.bounded("start_offboard()", ob.stop)
            raise
        except BaseException:
            self.stop_streaming()
            raise
        self._confirmed = True
        self.watchdog.arm()

    def set_goal(self, setpoint: Setpoint) -> None:
        ended = self._ended
        if ended is not None:
            why, detail = ended
            raise ModeChangedExternally(
                "MODE_CHANGED" if why == "external" else "WATCHDOG_HOLD", "set_setpoint()",
                (setpoint,), detail + ": our offboard control has ended; call "
                "start_offboard() to take it back")
        if not self.active:
            raise VehicleError("OFFBOARD_NOT_ACTIVE", "set_setpoint()", (setpoint,),
                               "call start_offboard() first")
        self._goal = setpoint
        self.watchdog.feed()

    def stop_streaming(self) -> None:
        """Our offboard control ends (a command changes the mode)."""
        self.watchdog.disarm()
        self.active = False
        self._ended = None

    def on_mode(self, new: FlightMode, source: str) -> None:
        """After a mode change seen in telemetry."""
        if new == FlightMode.OFFBOARD and self.active:
            self._confirmed = True
        elif self.active and self._confirmed and source != "command":
            self._end("external", f"the flight mode is now {new.value} (changed by the pilot, a "
                      "ground station or a PX4 failsafe)")

    def _end(self, why: str, detail: str) -> None:
        was = self.active
        self.watchdog.disarm()
        self.active = False
        self._ended = (why, detail)
        if was:
            log.warning("offboard ended (%s): %s", why, detail)
            self._v.event(EVENT_MODE, f"offboard ended: {detail}",
                          {"from": FlightMode.OFFBOARD.value,
                           "to": self._v.telemetry.cache.mode.value, "source": why})

    async def _loop(self) -> None:
        """The setpoint timer: independent of perception, ``offboard_rate_hz``."""
        v = self._v
        cfg = v.config
        period = 1.0 / cfg.offboard_rate_hz
        ob = v.plugins["Offboard"]
        now_ns = v.telemetry.now_ns
        last = now_ns()
        while True:
            await asyncio.sleep(period)
            now = now_ns()
            dt, last = min((now - last) * 1e-9, 0.5), now
            if not self.active or self._goal is None or self._cmd is None:
                continue
            cmd = step_towards(self._cmd, self._goal, dt, max_speed_mps=cfg.offboard_max_speed_mps,
                               max_vertical_speed_mps=cfg.offboard_max_vertical_speed_mps,
                               max_yaw_rate_degps=cfg.offboard_max_yaw_rate_degps)
            self._cmd = cmd
            try:
                ob.set_position_ned(self._local_setpoint(cmd))  # non-blocking: queues a message
            except Exception as exc:
                if v.mavsdk and isinstance(exc, v.mavsdk["MavsdkError"]):
                    log.warning("offboard setpoint not sent: %s", exc)
                else:
                    raise

    def _watchdog_hold(self, age_s: float) -> None:
        """Watchdog thread: fresh setpoints stopped. MAVSDK's blocking calls need nothing from
        the (possibly blocked) event loop."""
        v = self._v
        self.active = False
        self._ended = ("watchdog", f"no fresh setpoint for {age_s:.2f} s "
                       f"(watchdog {self.watchdog_timeout_s:g} s): the watchdog commanded HOLD")
        v.telemetry.expected = {FlightMode.HOLD}
        v.event(EVENT_WATCHDOG, self._ended[1], {"age_s": round(age_s, 3)})
        ob, act = v.plugins.get("Offboard"), v.plugins.get("Action")
        try:
            if ob is not None:
                ob.stop()  # DO_SET_MODE hold + stop re-sending the last setpoint
                return
        except Exception as exc:  # noqa: BLE001 - fall back on a plain hold
            log.warning("watchdog: offboard.stop() failed (%s): trying action.hold()", exc)
        if act is not None:
            act.hold()
