"""The mission's actuator: every vehicle command, each bounded, never inside a machine callback
(transitions #465/#474/#713: long work must not run in callbacks).

Commands come through a queue (``arm_takeoff``, ``start_offboard``, ``grasp``, ``final``);
results go back as plain attributes the runner reads on the loop thread (``command_failed``,
``offboard``, ``grasp_done``, ``finished``). Before the first command its
:class:`~eaglemission.safety.autopilot_guard.AutopilotGuard` reads the autopilot's failsafe
parameters and sets those outside the envelope inside it (or refuses the flight); they are
restored after landing.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from eaglemission.missions.approach_config import GraspConfig, TimeoutsConfig
from eaglemission.missions.arm import ArmTracking
from eaglemission.missions.guidance import Guidance
from eaglemission.missions.log import MissionLog

from eaglemission import errors
from eaglemission.clock import Clock
from eaglemission.config import MissionFile, SafetyConfig
from eaglemission.interfaces import Manipulator, Vehicle
from eaglemission.safety.autopilot_guard import AutopilotGuard

log = logging.getLogger(__name__)

ARM_CHECK_S = 0.02
"""How often GRASP_READY checks an arm's measured tool-to-target error (mission clock)."""

COM_OBL_RC_ACT_NAMES = {0: "Position mode", 1: "Altitude mode", 2: "Manual", 3: "Return",
                        4: "Land", 5: "Hold", 6: "Terminate", 7: "Disarm"}


def failsafe_param_warnings(values: dict[str, float], safety: SafetyConfig) -> list[str]:
    """What a field team must know about PX4's own failsafes with this envelope (pure).

    PX4 flies RTL/land/takeoff at its own speeds and RTL climbs to RTL_RETURN_ALT: values
    outside the mission's envelope are reported, as is the offboard-loss action (in the recorded
    PX4 traffic, offboard loss switched to Position mode and, without RC, the vehicle descended
    and landed)."""
    out: list[str] = []
    rtl = values.get("RTL_RETURN_ALT")
    if rtl is not None and rtl > safety.max_altitude_m:
        out.append(f"RTL_RETURN_ALT={rtl:g} m is above safety.max_altitude_m="
                   f"{safety.max_altitude_m:g}: a PX4 return would leave the altitude band; "
                   "set RTL_RETURN_ALT inside it")
    for name, limit in (("MPC_XY_CRUISE", safety.max_horizontal_speed_mps),
                        ("MPC_XY_VEL_MAX", safety.max_horizontal_speed_mps),
                        ("MPC_Z_VEL_MAX_UP", safety.max_vertical_speed_mps),
                        ("MPC_Z_VEL_MAX_DN", safety.max_vertical_speed_mps)):
        v = values.get(name)
        if v is not None and v > limit + 1e-6:
            out.append(f"{name}={v:g} m/s exceeds the envelope's {limit:g} m/s: autopilot-flown "
                       "moves (RTL, land, takeoff) would be faster than the envelope allows")
    act = values.get("COM_OBL_RC_ACT")
    if act is not None:
        out.append(f"offboard loss (COM_OF_LOSS_T={values.get('COM_OF_LOSS_T', float('nan')):g} "
                   f"s) -> COM_OBL_RC_ACT={int(act)} "
                   f"({COM_OBL_RC_ACT_NAMES.get(int(act), 'unknown')})"
                   + ("; without RC PX4 then descends and lands" if int(act) in (0, 1) else ""))
    return out


class Actuator:
    """Executes the mission's vehicle commands in order (one task), bounded by ``timeouts``;
    the grasp as ``grasp.action`` says, then held for ``grasp_hold_s``."""

    def __init__(self, cfg: MissionFile, vehicle: Vehicle, clock: Clock,
                 mission_log: MissionLog, guidance: Guidance, *, grasp: GraspConfig,
                 timeouts: TimeoutsConfig, grasp_hold_s: float,
                 grasp_callback: Callable[[], Awaitable[Any]] | None = None,
                 guard: AutopilotGuard | None = None, manipulator: Manipulator | None = None,
                 arm: ArmTracking | None = None) -> None:
        self.cfg, self.m = cfg, cfg.mission
        self.grasp_p, self.timeouts, self.grasp_hold_s = grasp, timeouts, grasp_hold_s
        self.vehicle, self.clock, self.log = vehicle, clock, mission_log
        self.guidance = guidance
        self.grasp_callback = grasp_callback
        self.queue: asyncio.Queue[tuple[str, Any]] = asyncio.Queue()
        self.stopping = False
        self.finished = asyncio.Event()
        self.command_failed = ""
        self.offboard = False
        self.offboard_since_ns = 0
        self.grasp_done = False
        self.final_sent = False
        self.settle_s = timeouts.settle_s
        self.failsafe_params: dict[str, float] | None = None
        self.failsafe_warnings: list[str] = []
        self.guard = guard or AutopilotGuard(self._inner(), cfg.safety, self.m.cruise_altitude_m,
                                             timeout_s=timeouts.command_s)
        self.refused = ""
        self.on_grasp_done: Callable[[], None] | None = None
        self.manipulator = manipulator
        self.arm = arm if arm is not None and arm.enabled else None
        """An arm (None: a fixed tool, the vehicle brought it within the tolerance before
        GRASP_READY)."""
        self.gripper_closed = False
        self.gripper_closed_ns: int | None = None
        self.tool_body_at_close_m: tuple[float, float, float] | None = None
        self.grasp_error_at_close_m: float | None = None

    def submit(self, name: str, arg: Any = None) -> None:
        self.queue.put_nowait((name, arg))

    def _inner(self) -> Vehicle:
        """The driver under the envelope (its parameters are the autopilot's)."""
        inner: Vehicle = getattr(self.vehicle, "inner", self.vehicle)
        return inner

    async def command(self, name: str, coro_fn: Callable[[], Awaitable[Any]]) -> bool:
        timeout = self.timeouts.command_s
        try:
            await asyncio.wait_for(coro_fn(), timeout=timeout)
        except (errors.DriverError, TimeoutError) as exc:  # refused, or a bounded wait ran out
            self.log.write("command", name=name, ok=False, error=str(exc))
            return False
        self.log.write("command", name=name, ok=True)
        return True

    async def run(self) -> None:
        v = self.vehicle
        manip = self.manipulator
        if manip is not None and self.arm is not None:  # an arm: home it first
            if not await self.command("manipulator_start", lambda: manip.start(
                    timeout_s=self.timeouts.command_s)):
                self.failsafe_warnings.append("the arm did not start (see the log)")
        await self.guard_autopilot()
        while not self.stopping:
            try:
                name, arg = await asyncio.wait_for(self.queue.get(), timeout=0.5)
            except TimeoutError:
                continue
            if name == "arm_takeoff":
                if self.refused:  # never armed: the autopilot would leave the envelope
                    self.command_failed = f"autopilot parameters: {self.refused}"
                    continue
                ok = await self.command("arm", v.arm) and await self.command(
                    "takeoff", lambda: v.takeoff(self.m.cruise_altitude_m))
                if not ok:
                    self.command_failed = "arm/takeoff refused"
            elif name == "start_offboard":
                vs = v.state()
                sp = self.guidance.start_at(vs.position_ned_m, vs.yaw_deg)
                if await self.command("start_offboard", functools.partial(v.start_offboard, sp)):
                    self.offboard = True
                    self.offboard_since_ns = self.clock.now_ns()
                else:
                    self.command_failed = "offboard refused"
            elif name == "grasp":
                await self.grasp()
            elif name == "final":
                try:
                    await self.final(arg)
                    if not v.state().in_air:
                        await self.restore_autopilot()
                finally:
                    self.finished.set()
                return

    async def grasp(self) -> None:
        action = self.grasp_p.action
        if action == "gripper":
            if self.arm is not None and not await self._arm_within_tolerance():
                return  # not reached: GRASP_READY's timeout ends the flight (on_timeout)
            self._gripper_closing()
            manip = self.manipulator
            close: Callable[[], Awaitable[Any]] = self.vehicle.grab if manip is None else (
                lambda: manip.close_gripper(timeout_s=self.timeouts.command_s))
            await self.command("grab", close)
        elif action == "callback" and self.grasp_callback is not None:
            try:
                await asyncio.wait_for(self.grasp_callback(), timeout=self.timeouts.grasp_ready_s)
                self.log.write("command", name="grasp_callback", ok=True)
            except Exception as exc:  # a user callback must not crash the mission
                self.log.write("command", name="grasp_callback", ok=False, error=repr(exc))
        # hold the grasp pose on the live estimate for the stable period before leaving
        await self.clock.sleep(max(0.0, self.grasp_hold_s))
        self.grasp_done = True
        if self.on_grasp_done is not None:
            self.on_grasp_done()

    async def _arm_within_tolerance(self) -> bool:
        """Wait (at most ``timeouts.grasp_ready_s``) until the arm's measured tool-to-target
        error is within ``grasp.tolerance_m`` with the arm settled at the point last commanded
        (closing while the tool still moves spends the arm's precision); False when it never
        was."""
        assert self.arm is not None
        tol = self.grasp_p.tolerance_m
        deadline = self.clock.now_ns() + int(self.timeouts.grasp_ready_s * 1e9)
        while not self.stopping:
            err = self.arm.measured_error()
            if err is not None and err <= tol and self.arm.settled():
                self.grasp_error_at_close_m = err
                return True
            if self.clock.now_ns() > deadline:
                break
            await self.clock.sleep(ARM_CHECK_S)
        self.log.write("event", source="mission",
                       text=f"the arm's tool did not come within grasp.tolerance_m={tol:g} m "
                       "of the target: the gripper stays open")
        return False

    def _gripper_closing(self) -> None:
        """Note when the gripper is commanded to close and where the tool is then (the
        manipulator's read-back; the fixed tool point without one); stop the arm."""
        self.gripper_closed = True
        self.gripper_closed_ns = self.clock.now_ns()
        if self.manipulator is not None:
            t = self.manipulator.report().tool_body_m
        else:
            t = self.cfg.tool_point_m
        self.tool_body_at_close_m = (float(t[0]), float(t[1]), float(t[2]))
        self.log.write("gripper", closing=True, tool_body_m=self.tool_body_at_close_m,
                       measured_error_m=self.grasp_error_at_close_m)
        if self.arm is not None:
            self.arm.hold()

    async def final(self, action: str) -> None:
        v = self.vehicle
        self.log.write("event", source="mission", text=f"final action: {action}")
        if action in ("hold", "land", "return"):
            was_offboard, self.offboard = self.offboard, False
            if was_offboard:  # leave offboard explicitly (MAVSDK: offboard.stop()) first
                await self.command("stop_offboard", v.stop_offboard)
            fn = {"hold": v.hold, "land": v.land, "return": v.return_to_launch}[action]
            deadline = self.clock.now_ns() + int(self.settle_s * 1e9)
            while not await self.command(action, fn):
                if self.clock.now_ns() > deadline:
                    break
                await self.clock.sleep(1.0)  # e.g. the link is down: retry
        elif action == "release":
            self.offboard = False  # stop commanding: the pilot has the vehicle
        self.final_sent = True
        # let the flight finish (landing / return) so the whole flight is recorded
        if action in ("land", "return"):
            deadline = self.clock.now_ns() + int(self.settle_s * 1e9)
            while self.clock.now_ns() < deadline:
                vs = v.state()
                if not vs.in_air and not vs.armed:
                    break
                await self.clock.sleep(0.5)
        else:
            await self.clock.sleep(2.0)

    async def guard_autopilot(self) -> None:
        """Read the autopilot's failsafe parameters, set those outside the envelope inside it
        or refuse (:mod:`eaglemission.safety.autopilot_guard`); one ``autopilot_params`` record, one
        ``param_set`` per change and the old values in ``failsafe_params``."""
        rep = await self.guard.apply()
        if not rep.available:
            self.log.write("failsafe_params", available=False)
            return
        self.failsafe_params = dict(rep.values)
        self.log.write("autopilot_params", **rep.record())
        for c in rep.set_ok:
            self.log.write("param_set", name=c.name, was=c.old, now=c.new,
                           envelope_key=c.envelope_key, reason=c.reason)
        if rep.missing:
            self.failsafe_warnings.append("not on this autopilot (read once): "
                                          + ", ".join(sorted(rep.missing)))
        if rep.refused:
            self.refused = rep.refused
            self.failsafe_warnings.append(f"refused: {rep.refused}")
            log.error("autopilot parameters: %s", rep.refused)
        # the values as PX4 will fly them (after the sets), for the report-only warnings
        flown = rep.values | {c.name: c.new for c in rep.set_ok}
        warnings = failsafe_param_warnings(flown, self.cfg.safety)
        self.failsafe_warnings.extend(warnings)
        self.log.write("failsafe_params", available=True, values=rep.values, flown=flown,
                       missing=sorted(rep.missing), warnings=warnings)
        for w in warnings:  # the run's summary shows them (report_lines): once, there
            log.info("PX4 failsafe parameters: %s", w)

    async def restore_autopilot(self) -> None:
        """Restore what :meth:`guard_autopilot` set (after landing; idempotent)."""
        for r in await self.guard.restore(in_air=self.vehicle.state().in_air):
            self.log.write("param_set", **r)
