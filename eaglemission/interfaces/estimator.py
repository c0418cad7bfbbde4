"""Estimator role (entry-point group ``eaglemission.estimators``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from eaglemission.geometry import CameraModel, Pose, camera_pose_ned
from eaglemission.types import Detection, EstimationFailed, TargetEstimate, VehicleState


@dataclass(frozen=True)
class CameraView:
    """A camera and the vehicle state at the frame's mid-exposure time."""

    model: CameraModel
    vehicle: VehicleState
    timestamp_ns: int

    @property
    def camera_pose_ned(self) -> Pose:
        """Optical -> NED."""
        return camera_pose_ned(self.model, self.vehicle.position_ned_m, self.vehicle.attitude_q)


@runtime_checkable
class Estimator(Protocol):
    """Turns a detection into a target position.

    Construction: ``cls(config=<cls.Config instance>, target=TargetConfig, **context)``.
    Returns a truthy :class:`TargetEstimate` or a falsy :class:`EstimationFailed` with the
    reason; misuse (bad shapes) raises ``ValueError``.
    """

    def estimate(
        self, detection: Detection, view: CameraView
    ) -> TargetEstimate | EstimationFailed: ...
