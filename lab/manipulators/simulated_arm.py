"""Manipulator ``simulated_arm``: a kinematic Cartesian arm under the body (an X-Y stage with a
Z slide) that carries the tool around its home point ``tool_point_m``.

Each joint is one body axis (metres from home, body FRD). A command reaches the joints
``latency_s`` after it is sent, clamped to the workspace; each joint then moves towards it at
up to ``joint_speed_mps`` (no overshoot). The state is integrated lazily on the mission clock
whenever it is read, so virtual-time flights are deterministic. The gripper closes in
``gripper_close_s``. The arm registers itself in the flight's shared context so the synthetic
cameras draw it (:mod:`eaglemission.lab.world.render`).
"""

from __future__ import annotations

import bisect
import collections
import threading
from typing import Annotated, Any

from eaglemission.lab.world.arm_drawing import ARM_BLOCK_M
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.clock import Clock
from eaglemission.errors import ConfigError, TimeoutError_
from eaglemission.flight.context import MANIPULATOR, SharedContext
from eaglemission.geometry.tool_marker import ToolMarker
from eaglemission.geometry.workspace import Workspace
from eaglemission.interfaces import ToolReport
from eaglemission.types import XYZ

_HISTORY_NS = 2_000_000_000
"""How far back ``tool_body_at`` answers (a camera renders up to its time offset earlier)."""


class SimulatedArmConfig(BaseModel):
    """The arm's workspace (at most +-0.10 m across the body), joint speeds and latency."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    workspace: Workspace = Field(default_factory=Workspace)
    joint_speed_mps: Annotated[float, Field(gt=0, le=5)] = Field(
        0.5, description="largest speed of each joint (body axis)")
    latency_s: Annotated[float, Field(ge=0, le=1)] = Field(
        0.04, description="from a command to the joints starting to move")
    gripper_close_s: Annotated[float, Field(ge=0, le=5)] = Field(
        0.3, description="from the close command to the gripper closed")
    drawn: bool = Field(True, description="the synthetic cameras draw the arm where it is "
                        "in view")
    tool_radius_m: Annotated[float, Field(gt=0, le=0.3)] = Field(
        ARM_BLOCK_M / 2, description="half the side of a cube around the tool point that "
        "holds the gripper as the cameras see it (the target's fit leaves out what it hides); "
        "the drawn gripper block's by default")
    marker: ToolMarker | None = Field(
        None, description="an ArUco marker on the gripper's back face, e.g. {} for the "
        "defaults (the cameras measure the tool by it: docs/manipulators.md); null: none")

    def model_post_init(self, _context: Any) -> None:
        ws = self.workspace
        across = max(ws.half_extent_m[:2]) if ws.shape == "box" else ws.radius_m
        if across > 0.10 + 1e-9:
            raise ValueError(f"workspace: reaches {across:g} m across the body; the simulated "
                             "arm reaches at most 0.10 m: make half_extent_m / radius_m <= 0.10")


class SimulatedArm:
    """Plugin ``simulated_arm`` (:class:`~eaglemission.interfaces.Manipulator`)."""

    Config = SimulatedArmConfig
    description = ("kinematic X-Y-Z arm under the body: workspace, joint speed and latency "
                   "(simulation)")

    def __init__(self, config: SimulatedArmConfig | None = None, *, clock: Clock | None = None,
                 tool_point_m: XYZ = (0.0, 0.0, 0.3), shared: SharedContext | None = None,
                 **_context: Any) -> None:
        if clock is None:
            raise ConfigError("manipulator.type simulated_arm: needs the mission clock (build "
                              "it through the assembly)")
        self.config = config or SimulatedArmConfig()
        self.clock = clock
        self.home_m: XYZ = (float(tool_point_m[0]), float(tool_point_m[1]),
                            float(tool_point_m[2]))
        self.workspace: Workspace | None = self.config.workspace
        self.marker: ToolMarker | None = self.config.marker
        self.tool_radius_m = self.config.tool_radius_m
        self._lock = threading.Lock()
        self._t_ns: int | None = None
        self._joints: list[float] = [0.0, 0.0, 0.0]
        self._goal: list[float] = [0.0, 0.0, 0.0]
        self._pending: collections.deque[tuple[int, XYZ]] = collections.deque()
        self._history: collections.deque[tuple[int, XYZ]] = collections.deque()
        self._closed = False
        self.commands = 0
        if shared is not None and self.config.drawn:
            shared.get_or_create(MANIPULATOR, lambda: self)

    # -- kinematics (lock held) -------------------------------------------------------------
    def _move(self, dt_s: float) -> None:
        step = self.config.joint_speed_mps * dt_s
        for i in range(3):
            d = self._goal[i] - self._joints[i]
            self._joints[i] += max(-step, min(step, d))

    def _advance(self, t_ns: int) -> None:
        if self._t_ns is None:
            self._t_ns = t_ns
        while self._pending and self._pending[0][0] <= t_ns:
            t_cmd, goal = self._pending.popleft()
            if t_cmd > self._t_ns:
                self._move((t_cmd - self._t_ns) * 1e-9)
                self._t_ns = t_cmd
            self._goal = list(goal)
        if t_ns > self._t_ns:
            self._move((t_ns - self._t_ns) * 1e-9)
            self._t_ns = t_ns
        j = (self._joints[0], self._joints[1], self._joints[2])
        if not self._history or self._history[-1][0] < self._t_ns:
            self._history.append((self._t_ns, j))
        while self._history and self._history[0][0] < self._t_ns - _HISTORY_NS:
            self._history.popleft()

    def _tool(self, joints: XYZ) -> XYZ:
        h = self.home_m
        return (h[0] + joints[0], h[1] + joints[1], h[2] + joints[2])

    # -- the role ----------------------------------------------------------------------------
    async def start(self, *, timeout_s: float) -> None:
        with self._lock:
            self._advance(self.clock.now_ns())

    def report(self) -> ToolReport:
        with self._lock:
            self._advance(self.clock.now_ns())
            j = (self._joints[0], self._joints[1], self._joints[2])
            t = int(self._t_ns or 0)
        return ToolReport(t, self._tool(j), j, self._closed, None)

    async def move_to(self, tool_body_m: XYZ, *, timeout_s: float) -> None:
        assert self.workspace is not None
        h = self.home_m
        goal = self.workspace.clamp_offset((tool_body_m[0] - h[0], tool_body_m[1] - h[1],
                                            tool_body_m[2] - h[2]))
        now = self.clock.now_ns()
        with self._lock:
            self._advance(now)
            self._pending.append((now + int(self.config.latency_s * 1e9), goal))
            self.commands += 1

    async def close_gripper(self, *, timeout_s: float) -> None:
        if self.config.gripper_close_s > timeout_s:
            await self.clock.sleep(timeout_s)
            raise TimeoutError_("close_gripper()", timeout_s,
                                f"the simulated gripper closes in {self.config.gripper_close_s:g}"
                                " s: raise the mission's timeouts.command_s or lower "
                                "manipulator.params.gripper_close_s")
        await self.clock.sleep(self.config.gripper_close_s)
        self._closed = True

    async def stop(self, *, timeout_s: float) -> None:
        with self._lock:
            self._advance(self.clock.now_ns())
            self._pending.clear()
            self._goal = list(self._joints)

    # -- for the synthetic cameras -------------------------------------------------------
    def tool_body_at(self, timestamp_ns: int) -> XYZ:
        """The tool point in body FRD at a time (at most the clock's now; the history for
        earlier times, the oldest kept before that)."""
        with self._lock:
            if self._t_ns is None or timestamp_ns >= self._t_ns:
                self._advance(min(int(timestamp_ns), self.clock.now_ns()))
                j = (self._joints[0], self._joints[1], self._joints[2])
            else:
                times = [t for t, _ in self._history]
                i = max(0, bisect.bisect_right(times, timestamp_ns) - 1)
                j = self._history[i][1] if self._history else (0.0, 0.0, 0.0)
        return self._tool(j)

    def summary(self) -> str:
        ws = self.workspace
        assert ws is not None
        return (f"simulated X-Y-Z arm: {ws.describe()}, {self.config.joint_speed_mps:g} m/s per "
                f"joint, latency {self.config.latency_s * 1e3:.0f} ms")
