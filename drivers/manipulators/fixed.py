"""Manipulator ``fixed``: a rigid tool at the mission file's ``tool_point_m`` and the
autopilot's gripper (the vehicle's ``grab``). It cannot move, so it has no workspace: the
vehicle alone brings the tool within ``grasp.tolerance_m`` of the target."""

from __future__ import annotations

import asyncio
from typing import Any

from pydantic import BaseModel, ConfigDict

from eaglemission.clock import Clock
from eaglemission.errors import ConfigError
from eaglemission.interfaces import ToolReport
from eaglemission.types import XYZ


class FixedToolConfig(BaseModel):
    """The fixed tool has nothing to set: its point is the mission file's ``tool_point_m``,
    its gripper the autopilot's (``vehicle.params.gripper_instance`` for MAVSDK)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class FixedTool:
    """Plugin ``fixed`` (:class:`~eaglemission.interfaces.Manipulator`)."""

    Config = FixedToolConfig
    description = "a rigid tool at tool_point_m, the autopilot's gripper (the vehicle's grab)"

    def __init__(self, config: FixedToolConfig | None = None, *, vehicle: Any = None,
                 clock: Clock | None = None, tool_point_m: XYZ = (0.0, 0.0, 0.3),
                 **_context: Any) -> None:
        self.config = config or FixedToolConfig()
        self.vehicle = vehicle
        self.clock = clock
        self.home_m: XYZ = (float(tool_point_m[0]), float(tool_point_m[1]),
                            float(tool_point_m[2]))
        self.workspace = None
        self._closed = False

    def _now_ns(self) -> int:
        return 0 if self.clock is None else int(self.clock.now_ns())

    async def start(self, *, timeout_s: float) -> None:
        return None

    def report(self) -> ToolReport:
        return ToolReport(self._now_ns(), self.home_m, (), self._closed, None)

    async def move_to(self, tool_body_m: XYZ, *, timeout_s: float) -> None:
        raise ConfigError("manipulator.type fixed: the tool cannot move; use an arm "
                          "(simulated_arm, actuator_servos) to move it")

    async def close_gripper(self, *, timeout_s: float) -> None:
        if self.vehicle is None:
            raise ConfigError("manipulator fixed: no vehicle to close the gripper with: build "
                              "it through the assembly (it hands the vehicle)")
        await asyncio.wait_for(self.vehicle.grab(), timeout=timeout_s)
        self._closed = True

    async def stop(self, *, timeout_s: float) -> None:
        return None

    def summary(self) -> str:
        h = self.home_m
        return f"fixed tool at ({h[0]:.2f}, {h[1]:.2f}, {h[2]:.2f}) m body FRD"
