"""Manipulator ``actuator_servos``: an arm whose joints are servos on the autopilot's actuator
outputs, driven with MAV_CMD_DO_SET_ACTUATOR (MAVSDK ``Action.set_actuator(index, value)``,
index 1-6, value -1..1) and read back from the autopilot's SERVO_OUTPUT_RAW.

PX4 drives an output with the function "Peripheral via Actuator Set N" (301-306, e.g.
``PWM_MAIN_FUNC5 = 301``) to the value of index N; outputs move only while armed unless
``COM_PREARM_MODE`` allows it. Each joint is one body axis of a Cartesian arm: ``min_m`` maps to
-1 and ``max_m`` to +1 (metres from the tool's home point, body FRD); the read-back maps the
output's pulse width between ``pwm_min_us`` and ``pwm_max_us`` back to metres. The tool's
reported position is that read-back, never the command.
"""

from __future__ import annotations

import asyncio
import time
from typing import Annotated, Any

from eaglemission.drivers.vehicles.mavsdk.outputs import ServoOutputs
from pydantic import BaseModel, ConfigDict, Field, model_validator

from eaglemission.errors import ConfigError, DriverError, TimeoutError_
from eaglemission.geometry.tool_marker import ToolMarker
from eaglemission.geometry.workspace import Workspace
from eaglemission.interfaces import ToolReport
from eaglemission.types import XYZ

_Index = Annotated[int, Field(ge=1, le=6)]
_Output = Annotated[int, Field(ge=1, le=16)]


class JointConfig(BaseModel):
    """One joint: the actuator-set index it is commanded on, the output it is read back from,
    and its travel (metres from home along its body axis) at -1 and +1."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    index: _Index
    output: _Output = Field(description="the autopilot output (SERVO_OUTPUT_RAW servoN_raw) "
                            "that carries it, e.g. 5 for PWM_MAIN_FUNC5 = 301")
    min_m: float = -0.10
    max_m: float = 0.10

    @model_validator(mode="after")
    def _travel(self) -> JointConfig:
        if not self.max_m > self.min_m:
            raise ValueError(f"max_m ({self.max_m:g}) must be greater than min_m "
                             f"({self.min_m:g})")
        return self

    def value_of(self, offset_m: float) -> float:
        """The actuator value (-1..1) for a joint offset, clamped to the travel."""
        u = -1.0 + 2.0 * (offset_m - self.min_m) / (self.max_m - self.min_m)
        return max(-1.0, min(1.0, u))

    def offset_of(self, value: float) -> float:
        return self.min_m + (value + 1.0) * 0.5 * (self.max_m - self.min_m)


def _default_joints() -> tuple[JointConfig, JointConfig, JointConfig]:
    return (JointConfig(index=1, output=5), JointConfig(index=2, output=6),
            JointConfig(index=3, output=7, min_m=-0.08, max_m=0.08))


class ServoArmConfig(BaseModel):
    """The joints (body x, y, z) on the autopilot's actuator outputs, the workspace and the
    gripper."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    joints: tuple[JointConfig, JointConfig, JointConfig] = Field(
        default_factory=_default_joints, description="body x, y, z joints")
    workspace: Workspace = Field(default_factory=Workspace)
    pwm_min_us: Annotated[int, Field(ge=500, le=2500)] = 1000
    pwm_max_us: Annotated[int, Field(ge=500, le=2500)] = 2000
    deadband_m: Annotated[float, Field(ge=0, le=0.05)] = Field(
        0.002, description="a joint is commanded again only when its goal moved this much")
    readback_tolerance_m: Annotated[float, Field(gt=0, le=0.05)] = Field(
        0.003, description="a joint read back within this of its command counts as there")
    readback_max_age_s: Annotated[float, Field(gt=0, le=10)] = Field(
        0.5, description="the read-back is stale after this long (PX4 sends it at 10 Hz)")
    gripper_index: _Index | None = Field(
        None, description="actuator-set index of a servo gripper (+1 closed); null: the "
        "autopilot's gripper (DO_GRIPPER, the vehicle's grab)")
    gripper_output: _Output | None = None
    tool_radius_m: Annotated[float, Field(gt=0, le=0.3)] = Field(
        0.04, description="half the side of a cube around the tool point that holds the "
        "gripper as the cameras see it (the target's fit leaves out what it hides)")
    marker: ToolMarker | None = Field(
        None, description="an ArUco marker fixed to the gripper, where it is: the cameras "
        "measure the tool by it (docs/manipulators.md); null: none")

    @model_validator(mode="after")
    def _consistent(self) -> ServoArmConfig:
        if self.pwm_max_us <= self.pwm_min_us:
            raise ValueError("pwm_max_us must be greater than pwm_min_us")
        idx = [j.index for j in self.joints] + ([self.gripper_index]
                                               if self.gripper_index is not None else [])
        if len(set(idx)) != len(idx):
            raise ValueError(f"joints and gripper_index share an actuator index: {idx}")
        ws = self.workspace
        reach = ws.half_extent_m if ws.shape == "box" else (ws.radius_m, ws.radius_m,
                                                            ws.half_height_m)
        for axis, j, r in zip("xyz", self.joints, reach):
            if j.min_m > -r + 1e-9 or j.max_m < r - 1e-9:
                raise ValueError(f"joints[{'xyz'.index(axis)}] travels {j.min_m:g}..{j.max_m:g} m "
                                 f"but the workspace reaches +-{r:g} m along body {axis}: widen "
                                 "the joint's travel or shrink the workspace")
        return self


class ServoArm:
    """Plugin ``actuator_servos`` (:class:`~eaglemission.interfaces.Manipulator`) on the
    ``mavsdk`` vehicle."""

    Config = ServoArmConfig
    description = ("Cartesian arm on the autopilot's actuator outputs (DO_SET_ACTUATOR), read "
                   "back from SERVO_OUTPUT_RAW")
    wall_clock = True

    def __init__(self, config: ServoArmConfig | None = None, *, vehicle: Any = None,
                 tool_point_m: XYZ = (0.0, 0.0, 0.3), **_context: Any) -> None:
        self.config = config or ServoArmConfig()
        self.vehicle = vehicle
        self.home_m: XYZ = (float(tool_point_m[0]), float(tool_point_m[1]),
                            float(tool_point_m[2]))
        self.workspace: Workspace | None = self.config.workspace
        self.marker: ToolMarker | None = self.config.marker
        self.tool_radius_m = self.config.tool_radius_m
        self._sent: list[float | None] = [None, None, None]
        self._goal: XYZ = (0.0, 0.0, 0.0)
        self._sender: asyncio.Task[None] | None = None
        self._closed = False
        self.sent_ns: list[tuple[int, int, float]] = []
        """(host ns, index, value) of every command sent (the read-back delay is measured
        against it)."""

    @classmethod
    def config_problems(cls, mission: Any, path: str) -> list[str]:
        if mission.vehicle.type != "mavsdk":
            return [f"{path}.type actuator_servos: drives the autopilot's outputs through the "
                    f"mavsdk vehicle, not {mission.vehicle.type!r}: use vehicle.type mavsdk, or "
                    "manipulator.type simulated_arm in simulation"]
        return []

    def _driver(self) -> Any:
        """The MAVSDK driver under the envelope and recording wrappers."""
        v = self.vehicle
        for _ in range(5):
            if v is None or hasattr(v, "servo_outputs"):
                break
            v = getattr(v, "inner", None)
        if v is None or not hasattr(v, "set_actuator"):
            raise ConfigError("manipulator.type actuator_servos: the vehicle is not the mavsdk "
                              "driver (no set_actuator / SERVO_OUTPUT_RAW): use vehicle.type "
                              "mavsdk")
        return v

    # -- conversions -------------------------------------------------------------------------
    def _value_of_pwm(self, pwm_us: int) -> float:
        c = self.config
        return -1.0 + 2.0 * (pwm_us - c.pwm_min_us) / (c.pwm_max_us - c.pwm_min_us)

    def joints_of(self, outputs: ServoOutputs) -> XYZ | None:
        """The joint offsets (m) an output message reports; None if a joint's output is
        missing or outside the pulse range (900 us: disarmed)."""
        out = []
        c = self.config
        for j in c.joints:
            pwm = outputs.pwm_us[j.output - 1]
            if not c.pwm_min_us - 5 <= pwm <= c.pwm_max_us + 5:
                return None
            out.append(j.offset_of(max(-1.0, min(1.0, self._value_of_pwm(pwm)))))
        return (out[0], out[1], out[2])

    # -- the role ----------------------------------------------------------------------------
    async def start(self, *, timeout_s: float) -> None:
        """Command home (the outputs follow once the autopilot drives them: armed, or
        ``COM_PREARM_MODE``; :meth:`wait_joints` waits for the read-back)."""
        await self.move_to(self.home_m, timeout_s=timeout_s)

    def report(self) -> ToolReport:
        d = self._driver()
        latest = d.servo_outputs.latest()
        now = time.monotonic_ns()
        joints = None
        if latest is not None and (now - latest.received_ns) * 1e-9 <= \
                self.config.readback_max_age_s:
            joints = self.joints_of(latest)
        if joints is None:  # no fresh read-back: the tool is where it was last seen, unknown
            nan = float("nan")
            return ToolReport(now, (nan, nan, nan), (), self._closed, None)
        h = self.home_m
        return ToolReport(latest.received_ns if latest else now,
                          (h[0] + joints[0], h[1] + joints[1], h[2] + joints[2]), joints,
                          self._closed, None)

    async def move_to(self, tool_body_m: XYZ, *, timeout_s: float) -> None:
        assert self.workspace is not None
        h = self.home_m
        self._goal = self.workspace.clamp_offset((tool_body_m[0] - h[0], tool_body_m[1] - h[1],
                                                  tool_body_m[2] - h[2]))
        d = self._driver()
        async with asyncio.timeout(timeout_s):
            for i, j in enumerate(self.config.joints):
                last = self._sent[i]
                if last is not None and abs(last - self._goal[i]) < self.config.deadband_m:
                    continue
                value = j.value_of(self._goal[i])
                await d.set_actuator(j.index, value)
                self._sent[i] = self._goal[i]
                self.sent_ns.append((time.monotonic_ns(), j.index, value))

    async def wait_joints(self, joints_m: XYZ, *, timeout_s: float) -> float:
        """Wait until every joint reads back within ``readback_tolerance_m`` of ``joints_m``;
        the seconds it took. Raises TimeoutError_ naming the joints that did not arrive."""
        d = self._driver()
        t0 = time.monotonic()
        tol = self.config.readback_tolerance_m
        seen: XYZ | None = None
        while time.monotonic() - t0 < timeout_s:
            latest = d.servo_outputs.latest()
            seen = None if latest is None else self.joints_of(latest)
            if seen is not None and all(abs(a - b) <= tol for a, b in zip(seen, joints_m)):
                return time.monotonic() - t0
            await asyncio.sleep(0.01)
        got = "no SERVO_OUTPUT_RAW in the pulse range" if seen is None else \
            "read back " + ", ".join(f"{v:+.3f}" for v in seen) + " m"
        raise TimeoutError_("wait_joints()", timeout_s,
                            f"joints commanded to {', '.join(f'{v:+.3f}' for v in joints_m)} m, "
                            f"{got}: check that PWM_MAIN_FUNCn = 300 + index for outputs "
                            f"{[j.output for j in self.config.joints]}, that the vehicle is "
                            "armed (or COM_PREARM_MODE = 2) and that SERVO_OUTPUT_RAW streams")

    async def close_gripper(self, *, timeout_s: float) -> None:
        c = self.config
        d = self._driver()
        if c.gripper_index is None:
            await asyncio.wait_for(self.vehicle.grab(), timeout=timeout_s)
        else:
            await asyncio.wait_for(d.set_actuator(c.gripper_index, 1.0), timeout=timeout_s)
            if c.gripper_output is not None:
                t0 = time.monotonic()
                while True:
                    latest = d.servo_outputs.latest()
                    if latest is not None and \
                            latest.pwm_us[c.gripper_output - 1] >= c.pwm_max_us - 5:
                        break
                    if time.monotonic() - t0 > timeout_s:
                        raise DriverError("GRIPPER_NOT_CLOSED", "close_gripper()", None,
                                          f"output {c.gripper_output} did not reach "
                                          f"{c.pwm_max_us} us within {timeout_s:g} s: check "
                                          f"PWM_MAIN_FUNC{c.gripper_output} = "
                                          f"{300 + c.gripper_index}")
                    await asyncio.sleep(0.02)
        self._closed = True

    async def stop(self, *, timeout_s: float) -> None:
        return None  # the outputs hold their last value

    def summary(self) -> str:
        ws = self.workspace
        assert ws is not None
        js = ", ".join(f"{a}: set {j.index} -> output {j.output}"
                       for a, j in zip("xyz", self.config.joints))
        return f"servo arm on actuator outputs ({js}), {ws.describe()}"
