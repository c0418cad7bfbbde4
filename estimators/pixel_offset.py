"""Coarse target offset from the detection centre, Eq. (16) of [1] as printed (plugin
``pixel_offset``).

.. math:: E_i = \\Delta p_i \\, \\beta_i \\, \\frac{FOV}{M_i}, \\quad i \\in \\{x, y\\}

The equation is not dimensionally self-evident. The reading used here (docs/paper_choices.md,
"Eq. (16), RPnP and the MBR corners"):

- ``delta_p`` [px]: target centre minus image centre along i (u right for x, v down for y);
- ``beta`` [dimensionless]: the pixel size along i *in units of the nominal pixel pitch*
  (1 for the Basler's square 3.75 um pixels; the pixel aspect ratio otherwise);
- ``FOV`` [m]: the **linear** field of view along i at the target's depth, i.e. the width of
  the scene the image spans there (``2 Z tan(fov_i / 2)``);
- ``M`` [px]: the resolution along i.

so ``FOV / M`` is metres per pixel at the target's depth and ``E`` is a metric offset parallel to
the image plane, in the camera optical frame (x right, y down), the "offset of the target in the
camera coordinate system from directions x and y" the paper describes. With beta a physical
length (3.75e-6 m) and FOV an angle, E would have units of m rad / px, which is not a distance.

The depth Z is not given by Eq. (16) (the paper: "only the relative position information
parallel to the imaging plane can be obtained"); the plugin takes it where the optical axis meets
the horizontal plane at the target's top height (``depth_source="optical_axis_ground"``), or a
fixed working distance (``"fixed"``, the paper's ~6 m of Period 1). The result is flagged
``full_3d=False``.

References
----------
.. [1] The source paper, Sec. 3.2, Eq. (16) (/work/shared/paper).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.geometry import intersect_ray_with_horizontal_plane
from eaglemission.interfaces.estimator import CameraView
from eaglemission.types import Detection, EstimationFailed, TargetEstimate

if TYPE_CHECKING:
    from eaglemission.config import TargetConfig


def eq16_offset(delta_p_px: float, beta: float, fov: float, resolution_px: float) -> float:
    """Eq. (16) of [1] as printed: ``E_i = delta_p_i * beta_i * FOV / M_i``.

    Parameters
    ----------
    delta_p_px : pixel difference between the target centre and the image centre along i
    beta : pixel size along i in units of the nominal pixel pitch (1 for square pixels)
    fov : linear field of view along i at the target's depth, metres
    resolution_px : image resolution along i, pixels

    Returns
    -------
    float : offset along i parallel to the image plane, metres (camera optical frame)
    """
    if not resolution_px > 0:
        raise ValueError(f"resolution_px: must be > 0, got {resolution_px}")
    return delta_p_px * beta * fov / resolution_px  # Eq. (16).


def linear_fov_m(fov_deg: float, depth_m: float) -> float:
    """Width of the scene an angular field of view spans at ``depth_m`` along the axis."""
    return 2.0 * depth_m * math.tan(math.radians(fov_deg) / 2.0)


class PixelOffsetConfig(BaseModel):
    """Params of the ``pixel_offset`` plugin."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    depth_source: Literal["optical_axis_ground", "fixed"] = "optical_axis_ground"
    fixed_depth_m: float = Field(default=6.0, gt=0, description="working distance when depth_source=fixed")
    max_depth_m: float = Field(default=60.0, gt=0, description="fail beyond this depth (near the horizon)")
    std_fraction: float = Field(default=0.3, gt=0, description="reported std as a fraction of the depth")


class PixelOffsetEstimator:
    """Plugin ``pixel_offset``: paper Eq. (16), offsets parallel to the image plane."""

    Config: ClassVar[type[PixelOffsetConfig]] = PixelOffsetConfig
    description: ClassVar[str] = "Eq. (16) of the paper: offset parallel to the image plane from the MBR centre"

    def __init__(self, config: PixelOffsetConfig | None = None, *,
                 target: TargetConfig | None = None, **context: object) -> None:
        self.config: PixelOffsetConfig = config if config is not None else PixelOffsetConfig()
        self.top_height_m = float(getattr(target, "height_m", 0.0) or 0.0)

    def estimate(self, detection: Detection, view: CameraView) -> TargetEstimate | EstimationFailed:
        model = view.model
        cfg = self.config
        cam = view.camera_pose_ned
        if cfg.depth_source == "fixed":
            depth = cfg.fixed_depth_m
        else:
            axis_ned = cam.R @ np.array([0.0, 0.0, 1.0])
            hit = intersect_ray_with_horizontal_plane(tuple(cam.t), tuple(axis_ned),
                                                      -self.top_height_m)
            if hit is None:
                return EstimationFailed("pixel_offset: the optical axis is at or above the horizon; "
                                        "no depth for Eq. (16) (use depth_source=fixed)")
            depth = float((cam.R.T @ (hit - cam.t))[2])
        if not 0 < depth <= cfg.max_depth_m:
            return EstimationFailed(f"pixel_offset: depth {depth:.1f} m outside (0, {cfg.max_depth_m:g}]")
        cu, cv = detection.center_px
        if not (math.isfinite(cu) and math.isfinite(cv)):
            return EstimationFailed("pixel_offset: detection centre is not finite")
        # Paper: difference to "the center of the image" (the principal point here).
        dpx, dpy = cu - model.cx, cv - model.cy
        fov_x_deg, fov_y_deg = model.fov_deg
        beta_x = 1.0
        beta_y = model.fy / model.fx  # pixel height in units of the pixel width (1: square)
        e_x = eq16_offset(dpx, beta_x, linear_fov_m(fov_x_deg, depth), model.width_px)
        e_y = eq16_offset(dpy, beta_y, linear_fov_m(fov_y_deg, depth), model.height_px)
        p_cam = np.array([e_x, e_y, depth])
        p_ned = cam.R @ p_cam + cam.t
        return TargetEstimate(
            position_ned_m=(float(p_ned[0]), float(p_ned[1]), float(p_ned[2])),
            position_cam_m=(float(e_x), float(e_y), float(depth)),
            timestamp_ns=int(view.timestamp_ns), camera_id=model.camera_id,
            source="pixel_offset", full_3d=False, std_m=cfg.std_fraction * depth)
