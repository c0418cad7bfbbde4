"""What the approach mission reports at the end (no ground truth: see the evaluator)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


@dataclass
class MissionResult:
    """What the mission itself knows at the end (no ground truth: see the evaluator)."""

    final_state: str
    reason: str
    action: str
    states: list[tuple[float, str, str]]
    t_start_s: float
    t_end_s: float
    t_grasp_ready_s: float | None = None
    estimated_tool_errors_m: tuple[float, float] | None = None
    t_gripper_closed_s: float | None = None
    """When the gripper was commanded to close (None: it was not)."""
    tool_body_at_close_m: tuple[float, float, float] | None = None
    """The tool point in body FRD then, as the manipulator read it back."""
    estimated_grasp_error_m: float | None = None
    """An arm's measured tool-to-target error when the gripper closed (None: a fixed tool)."""
    latencies_ms: list[float] = field(default_factory=list)
    frames_processed: dict[str, int] = field(default_factory=dict)
    frame_counts: dict[str, dict[str, int]] = field(default_factory=dict)
    """Per camera: grabbed, processed, skipped, dropped (missions/camera_pump.py)."""
    detections: dict[str, int] = field(default_factory=dict)
    detection_frames: list[tuple[float, str, str, int, tuple[float, float] | None]] = field(
        default_factory=list)
    """(t_s, camera, state, frame seq, detection centre px or None) per processed frame."""
    failsafe_params: dict[str, float] | None = None
    failsafe_warnings: list[str] = field(default_factory=list)
    perception_ms: list[float] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def reached_grasp_ready(self) -> bool:
        return self.t_grasp_ready_s is not None

    @property
    def latency_p90_ms(self) -> float:
        return percentile(self.latencies_ms, 90)
