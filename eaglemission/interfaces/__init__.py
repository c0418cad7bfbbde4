"""One Protocol per plugin role. They describe only what the core consumes."""

from eaglemission.interfaces.camera import Camera
from eaglemission.interfaces.detector import Detector
from eaglemission.interfaces.estimator import CameraView, Estimator
from eaglemission.interfaces.fitter import PlaneFitter
from eaglemission.interfaces.judge import Judge, Verdict
from eaglemission.interfaces.manipulator import Manipulator, ToolReport
from eaglemission.interfaces.mission import (
    FlightParts,
    FlightRecorder,
    Mission,
    MissionHooks,
    MissionOutcome,
)
from eaglemission.interfaces.section import Section
from eaglemission.interfaces.tracker import Tracker
from eaglemission.interfaces.truth import GroundTruth
from eaglemission.interfaces.vehicle import Vehicle
from eaglemission.interfaces.world import World

__all__ = ["Camera", "CameraView", "Detector", "Estimator", "FlightParts", "FlightRecorder",
           "GroundTruth", "Judge", "Manipulator", "Mission", "MissionHooks", "MissionOutcome",
           "PlaneFitter", "Section", "ToolReport", "Tracker", "Vehicle", "Verdict", "World"]
