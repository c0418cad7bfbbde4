"""What the PnP estimator plugins (``rpnp``, ``sqpnp``, ``ippe``, ``iterative``) share: the
params of the corner handling and the plugin body around one
:class:`~eaglemission.estimators.correspondence.CornerPoseEstimator`; each plugin brings its
solver."""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from eaglemission.estimators.correspondence import CornerPoseEstimator, Solver
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.interfaces.estimator import CameraView
from eaglemission.types import Detection, EstimationFailed, TargetEstimate

if TYPE_CHECKING:
    from eaglemission.config import TargetConfig


class CornerPnPConfig(BaseModel):
    """Params every PnP estimator plugin has: how a detection's MBR corners become a pose."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    mbr_correction: Literal["auto", "box_fit", "none"] = Field(
        default="auto", description="MBR model: auto = the better of box silhouette / top face alone; "
                            "box_fit = silhouette; none = MBR corners are the top face (paper)")
    max_reprojection_error_px: float = Field(
        default=8.0, gt=0, description="reject poses whose mean corner reprojection error is larger")
    previous_pose_weight_px_per_m: float = Field(
        default=20.0, ge=0, description="weight of the distance to the previous pose in the corner-order choice")
    std_m: float = Field(default=0.05, gt=0, description="reported 1-sigma position uncertainty at 1 m range")


class CornerPnPEstimator:
    """A PnP plugin: ``solver`` on the target's top face, inside one corner estimator
    (corner orders, MBR correction, the previous pose, NED conversion)."""

    def __init__(self, solver: Solver, config: CornerPnPConfig, *,
                 target: TargetConfig | None, source: str) -> None:
        self._core = CornerPoseEstimator(
            solver=solver, target=target, source=source, mbr_correction=config.mbr_correction,
            max_reprojection_error_px=config.max_reprojection_error_px,
            previous_pose_weight_px_per_m=config.previous_pose_weight_px_per_m,
            std_m=config.std_m, warm_up=True)

    @property
    def corners(self) -> CornerPoseEstimator:
        """The corner estimator doing the work: corner orders, candidates, MBR correction."""
        return self._core

    def reset(self) -> None:
        self._core.reset()

    def estimate(self, detection: Detection, view: CameraView) -> TargetEstimate | EstimationFailed:
        return self._core.estimate(detection, view)
