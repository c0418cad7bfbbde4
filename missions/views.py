"""Which camera sees the target: projected footprints and the dual camera's hand-over (paper
Sec. 3.2, Fig. 4: the wide camera searches, the narrow one measures once the target lies inside
its view drawn in the wide image).

Pure functions of camera models and vehicle states, and :class:`CameraChoice`, the small state
the mission keeps about it (loop thread only).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from eaglemission.geometry import CameraModel, camera_pose_ned
from eaglemission.geometry.fov import target_in_narrow_view
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.types import Detection, VehicleState


def project_target(model: CameraModel, state: VehicleState, target_ned_m: Sequence[float]
                   ) -> NDArray[np.float64]:
    """Pixel of a NED point in a camera on a vehicle (NaN when behind the camera)."""
    pose = camera_pose_ned(model, state.position_ned_m, state.attitude_q).inverse()
    px: NDArray[np.float64] = model.project(pose.apply(np.asarray(target_ned_m,
                                                                  dtype=np.float64)))[0]
    return px


def target_corners_ned(target_ned_m: Sequence[float], length_m: float, width_m: float,
                       yaw_deg: float = 0.0, pad_m: float = 0.0) -> NDArray[np.float64]:
    """The 4 top-face corners (plus ``pad_m``) of a target centred at ``target_ned_m``."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    hl, hw = length_m / 2 + pad_m, width_m / 2 + pad_m
    out = []
    for x, y in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw)):
        out.append((target_ned_m[0] + c * x - s * y, target_ned_m[1] + s * x + c * y,
                    target_ned_m[2]))
    return np.asarray(out)


def footprint_px(model: CameraModel, state: VehicleState, target_ned_m: Sequence[float],
                 length_m: float, width_m: float) -> NDArray[np.float64]:
    """Projected footprint (a square of the target's diagonal, any heading) in pixels (4, 2)."""
    d = math.hypot(length_m, width_m)
    pts = target_corners_ned(target_ned_m, d, d)
    pose = camera_pose_ned(model, state.position_ned_m, state.attitude_q).inverse()
    px: NDArray[np.float64] = model.project(pose.apply(pts))
    return px


def fully_in_image(model: CameraModel, px: NDArray[np.float64], margin_px: float) -> bool:
    return bool(np.isfinite(px).all() and model.in_image(px, margin_px).all())


def fill_fraction(model: CameraModel, px: NDArray[np.float64]) -> float:
    """Largest extent of projected points relative to the image size (inf when behind)."""
    if not np.isfinite(px).all():
        return math.inf
    span = px.max(axis=0) - px.min(axis=0)
    return float(max(span[0] / model.width_px, span[1] / model.height_px))


def wide_detection_in_narrow(det: Detection, wide: CameraModel, narrow: CameraModel,
                             state: VehicleState, target_ned_m: Sequence[float]) -> bool:
    """Paper Fig. 4(c): the wide-image detection lies inside the narrow camera's view drawn in
    the wide image (:func:`eaglemission.geometry.fov.target_in_narrow_view`)."""
    height = float(target_ned_m[2]) - float(state.position_ned_m[2])  # above the target's top
    if height <= 0:
        return False
    return bool(target_in_narrow_view(wide, narrow, det.corners_px,
                                      height_above_ground_m=height,
                                      attitude_q=state.attitude_q))


@dataclass(frozen=True, slots=True)
class ChoiceParams:
    warm_margin_px: float
    narrow_max_fill: float
    narrow_miss_switch_s: float
    image_border_px: float


class CameraChoice:
    """The dual camera's hand-over: whether the target lies in the narrow view (coarse
    approach), whether to warm the narrow detector, which camera the fine approach uses and
    whether the target should be visible in it."""

    def __init__(self, wide: CameraModel, narrow: CameraModel, length_m: float, width_m: float,
                 params: ChoiceParams) -> None:
        self.wide, self.narrow = wide, narrow
        self.length_m, self.width_m = length_m, width_m
        self.p = params
        self.reset_coarse()
        self.reset_fine()

    def reset_coarse(self) -> None:
        self.near_narrow = False
        self.target_in_narrow = False

    def reset_fine(self) -> None:
        self.fine_camera = CAMERA_NARROW
        self.narrow_miss_since_ns: int | None = None
        self.expected_visible = True

    def narrow_result(self, fine_ok: bool, now_ns: int) -> None:
        """A narrow frame was processed: with or without a fine estimate."""
        if fine_ok:
            self.narrow_miss_since_ns = None
        elif self.narrow_miss_since_ns is None:
            self.narrow_miss_since_ns = now_ns

    def update_coarse(self, state: VehicleState, target: Sequence[float], camera_id: str,
                      det: Detection | None) -> None:
        px_n = footprint_px(self.narrow, state, target, self.length_m, self.width_m)
        in_view = fully_in_image(self.narrow, px_n, 0.0)
        if camera_id == CAMERA_WIDE and det is not None:
            in_view = in_view and wide_detection_in_narrow(det, self.wide, self.narrow, state,
                                                           target)
        self.target_in_narrow = in_view
        margin_n = -self.p.warm_margin_px * self.narrow.fx / self.wide.fx
        self.near_narrow = self.near_narrow or fully_in_image(self.narrow, px_n, margin_n)

    def update_fine(self, state: VehicleState, target: Sequence[float], camera_id: str,
                    now_ns: int) -> str | None:
        """Returns the new fine camera when the narrow one can no longer serve."""
        px_n = footprint_px(self.narrow, state, target, self.length_m, self.width_m)
        fill_n = fill_fraction(self.narrow, px_n)
        narrow_ok = fully_in_image(self.narrow, px_n, 8.0) and fill_n <= self.p.narrow_max_fill
        narrow_silent = (camera_id == CAMERA_NARROW and self.narrow_miss_since_ns is not None
                         and (now_ns - self.narrow_miss_since_ns) * 1e-9
                         > self.p.narrow_miss_switch_s)
        switched = None
        if self.fine_camera == CAMERA_NARROW and (not narrow_ok or narrow_silent):
            self.fine_camera = switched = CAMERA_WIDE
            self.expected_visible = True
        px_w = footprint_px(self.wide, state, target, self.length_m, self.width_m)
        cam = self.narrow if self.fine_camera == CAMERA_NARROW else self.wide
        px_c = px_n if cam is self.narrow else px_w
        self.expected_visible = fully_in_image(cam, px_c, self.p.image_border_px)
        return switched
