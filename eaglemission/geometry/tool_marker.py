"""A fiducial marker on an arm's tool: what the cameras look for to see where the tool is.

An ArUco marker (OpenCV's predefined dictionaries) fixed to the tool, flat on one face of the
gripper, facing one body axis; the arm translates its tool without turning it, so the marker's
axes are fixed in the body frame. ``centre_from_tool_m`` places the marker's centre relative to
the tool point in body FRD.

Marker axes (OpenCV's convention for a marker seen face-on): x to the marker's right, y up the
marker, z out of its face towards the viewer. The corners, in ArUco's order, are top-left,
top-right, bottom-right, bottom-left (``SOLVEPNP_IPPE_SQUARE``'s order).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.types import XYZ

Facing = Literal["back", "front", "left", "right", "up"]

_AXES_BODY: dict[str, tuple[XYZ, XYZ, XYZ]] = {
    # facing: (marker x, marker y, marker z = the face's outward normal), body FRD; the marker's
    # top is up (-z body) on the side faces, forward (+x body) on the top face
    "back": ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0), (-1.0, 0.0, 0.0)),
    "front": ((0.0, -1.0, 0.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)),
    "left": ((-1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, -1.0, 0.0)),
    "right": ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "up": ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)),
}


class ToolMarker(BaseModel):
    """An ArUco marker on the tool (``manipulator.params.marker``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    dictionary: Literal["DICT_4X4_50", "DICT_5X5_50", "DICT_6X6_50", "DICT_APRILTAG_36h11"] = \
        Field("DICT_4X4_50", description="OpenCV predefined dictionary the marker is from")
    marker_id: Annotated[int, Field(ge=0, le=586)] = Field(7, description="its id there")
    side_m: Annotated[float, Field(gt=0.005, le=0.3)] = Field(
        0.04, description="side of the marker's black square (its outer border), m")
    facing: Facing = Field("back", description="the body axis the marker faces (back: towards "
                           "cameras mounted behind the tool)")
    centre_from_tool_m: tuple[float, float, float] = Field(
        (-0.021, 0.0, 0.0), description="the marker's centre from the tool point, body FRD, m")
    plate_m: Annotated[float, Field(ge=0, le=0.5)] = Field(
        0.05, description="side of the white plate it is printed on (its quiet zone), m; "
                          "at least side_m")

    def model_post_init(self, _context: object) -> None:
        if self.plate_m and self.plate_m < self.side_m:
            raise ValueError(f"plate_m={self.plate_m:g} is smaller than side_m={self.side_m:g}: "
                             "the plate carries the whole marker (0: no plate)")


def marker_axes_body(facing: Facing) -> npt.NDArray[np.float64]:
    """(3, 3): the marker's x, y, z axes as the columns, in body FRD."""
    return np.array(_AXES_BODY[facing], dtype=np.float64).T


def marker_corners_body(marker: ToolMarker, tool_body_m: XYZ, side_m: float | None = None
                        ) -> npt.NDArray[np.float64]:
    """(4, 3): the corners of the marker's square (or of a square of ``side_m`` on the same
    centre, e.g. its plate) in body FRD, ArUco's order, with the tool at ``tool_body_m``."""
    s = (marker.side_m if side_m is None else side_m) / 2
    local = np.array([[-s, s, 0.0], [s, s, 0.0], [s, -s, 0.0], [-s, -s, 0.0]])
    centre = np.asarray(tool_body_m, dtype=np.float64) + np.asarray(marker.centre_from_tool_m)
    out: npt.NDArray[np.float64] = centre + local @ marker_axes_body(marker.facing).T
    return out
