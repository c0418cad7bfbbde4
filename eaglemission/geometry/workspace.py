"""A manipulator's workspace: where its tool can go, in the body FRD frame, centred on the
tool's home point (``tool_point_m``).

A box (``half_extent_m`` per body axis) or an upright cylinder (``radius_m`` across, body x
and y; ``half_height_m`` along body z). ``margin_m`` shrinks it for the mission's readiness
check: a target inside the shrunk workspace can be reached with the margin to spare, while
the tool itself may use the whole workspace.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from eaglemission.types import XYZ

_NonNeg = Annotated[float, Field(ge=0, le=2.0, allow_inf_nan=False)]


class Workspace(BaseModel):
    """Where the tool can reach, relative to its home point, in body FRD (metres)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    shape: Literal["box", "cylinder"] = Field("box", description="box: `half_extent_m` per "
                                              "body axis; cylinder: `radius_m` across, "
                                              "`half_height_m` along body z")
    half_extent_m: tuple[_NonNeg, _NonNeg, _NonNeg] = Field(
        (0.10, 0.10, 0.08), description="box: half its size along body x, y, z")
    radius_m: _NonNeg = Field(0.10, description="cylinder: its radius across body x and y")
    half_height_m: _NonNeg = Field(0.08, description="cylinder: half its height along body z")
    margin_m: _NonNeg = Field(0.02, description="the mission's readiness check uses the "
                              "workspace shrunk by this much")

    def offset_inside(self, offset_m: Sequence[float], margin_m: float = 0.0) -> bool:
        """The offset from the home point lies inside the workspace shrunk by ``margin_m``."""
        x, y, z = (float(v) for v in offset_m)
        if self.shape == "box":
            return all(abs(v) <= h - margin_m for v, h in zip((x, y, z), self.half_extent_m))
        return (math.hypot(x, y) <= self.radius_m - margin_m
                and abs(z) <= self.half_height_m - margin_m)

    def clamp_offset(self, offset_m: Sequence[float]) -> XYZ:
        """The nearest offset inside the workspace (its boundary when outside)."""
        x, y, z = (float(v) for v in offset_m)
        if self.shape == "box":
            hx, hy, hz = self.half_extent_m
            return (min(hx, max(-hx, x)), min(hy, max(-hy, y)), min(hz, max(-hz, z)))
        r = math.hypot(x, y)
        k = 1.0 if r <= self.radius_m or r == 0.0 else self.radius_m / r
        hz = self.half_height_m
        return (x * k, y * k, min(hz, max(-hz, z)))

    def describe(self) -> str:
        if self.shape == "box":
            hx, hy, hz = self.half_extent_m
            return (f"box +-{hx * 100:.0f} x +-{hy * 100:.0f} x +-{hz * 100:.0f} cm, margin "
                    f"{self.margin_m * 100:.0f} cm")
        return (f"cylinder r {self.radius_m * 100:.0f} cm, +-{self.half_height_m * 100:.0f} cm "
                f"high, margin {self.margin_m * 100:.0f} cm")


def offset_from_home(point_body_m: Sequence[float], home_m: Sequence[float]) -> XYZ:
    return (float(point_body_m[0]) - float(home_m[0]), float(point_body_m[1]) - float(home_m[1]),
            float(point_body_m[2]) - float(home_m[2]))
