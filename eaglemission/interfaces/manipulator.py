"""Manipulator role (entry-point group ``eaglemission.manipulators``): the tool under the
vehicle, its workspace and its gripper.

The mission reads where the tool is (``report``: the tool point in body FRD as the arm's own
joint read-back puts it, the joints, the gripper) and, when the tool can move
(``workspace`` is not None), commands it towards a point in body FRD (``move_to``, clamped to
the workspace by the plugin). ``fixed`` (a rigid tool at ``tool_point_m``) has no workspace:
the vehicle alone brings the tool to the target.

Construction: ``cls(config=<cls.Config>, vehicle=<the assembly's vehicle (SafeVehicle)>,
clock=<the mission clock>, tool_point_m=<the mission file's home point>, shared=<the
flight's SharedContext>)``. Every command is bounded (``timeout_s``) and raises
:class:`~eaglemission.errors.EagleMissionError` subclasses whose message says what failed and
how to fix it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from eaglemission.geometry.workspace import Workspace
from eaglemission.types import XYZ


@dataclass(frozen=True, slots=True)
class ToolReport:
    """What a manipulator reports at one time (units in the names)."""

    timestamp_ns: int
    tool_body_m: XYZ
    """The tool point in body FRD (from the joints' read-back, not the command)."""
    joints: tuple[float, ...] = ()
    """Joint positions in the plugin's own units (metres for a Cartesian stage)."""
    gripper_closed: bool = False
    holding: bool | None = None
    """An object is held; None: the gripper has no sensor that says."""


@runtime_checkable
class Manipulator(Protocol):
    """The tool the mission grasps with (see the module docstring)."""

    home_m: XYZ
    """The tool's home point in body FRD (the mission file's ``tool_point_m``)."""
    workspace: Workspace | None
    """Where the tool can go around ``home_m``; None: it cannot move (``fixed``)."""
    # optional: ``marker`` (a :class:`~eaglemission.geometry.tool_marker.ToolMarker` or None),
    # a fiducial on the tool the cameras measure it by (missions/tool_sight.py);
    # ``tool_radius_m``, half the side of a cube around the tool point that holds what the
    # cameras see of the gripper (missions/arm.py, 0.04 m without it)

    async def start(self, *, timeout_s: float) -> None:
        """Ready the tool (connect, home it); bounded."""
        ...

    def report(self) -> ToolReport:
        """The latest read-back (non-blocking)."""
        ...

    async def move_to(self, tool_body_m: XYZ, *, timeout_s: float) -> None:
        """Command the tool towards a point in body FRD (clamped to the workspace); returns
        once the command is sent, not when the tool arrives."""
        ...

    async def close_gripper(self, *, timeout_s: float) -> None:
        """Close the gripper; returns when the gripper reports it closed."""
        ...

    async def stop(self, *, timeout_s: float) -> None:
        """Stop commanding (the tool stays where it is); idempotent."""
        ...
