"""The ``faults:`` section of a mission file: faults injected where they happen in life.

Each fault has a kind, a trigger (``at_s`` after the mission starts, or ``at_state`` + ``delay_s``
after the mission enters that state), a ``duration_s`` and, for some kinds, a ``size``. The
assembly (:mod:`eaglemission.lab.faults.injection`) hands camera faults to the ``faulty`` camera
wrapper, detector and estimator faults to the core wrappers, and vehicle and world faults to
the vehicle's injection methods; the expected outcome of each kind is
:data:`eaglemission.lab.faults.outcomes.OUTCOMES` (docs/faults.md).
"""

from __future__ import annotations

from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, model_validator

FaultKind = Literal[
    # camera (lab/faults/faulty_camera.py)
    "camera_drop", "camera_freeze", "corrupted_frame", "truncated_frame", "exposure_jump",
    "camera_device_loss", "camera_clock_jump", "occlusion",
    # detector and estimator (lab/faults/wrappers.py)
    "detector_exception", "nan_map", "slow_frame", "degenerate_corners", "pose_flip",
    # vehicle link and autopilot (lab/vehicles/simulated/faults.py)
    "link_loss", "command_denied", "pilot_mode", "gps_loss", "battery_drain",
    "link_delay", "link_duplicate", "link_reorder", "autopilot_clock_jump",
    # world (the vehicle's dynamics)
    "wind_gust",
]
FAULT_KINDS: tuple[str, ...] = get_args(FaultKind)

MissionStateName = Literal["PREFLIGHT", "TAKEOFF", "CRUISE", "COARSE_APPROACH",
                           "FINE_APPROACH", "GRASP_READY", "TARGET_LOST"]

# kinds whose `size` means something, with its unit and valid range (lo, hi], and the default
SIZES: dict[str, tuple[str, float, float, float]] = {
    "exposure_jump": ("gain factor on the image (x)", 0.0, 20.0, 3.0),
    "camera_clock_jump": ("jump of the camera's frame stamps (s)", -3600.0, 3600.0, 5.0),
    "slow_frame": ("extra processing time per frame (s)", 0.0, 10.0, 0.8),
    "battery_drain": ("battery fraction left after the drain", -1e-9, 1.0, 0.1),
    "link_delay": ("delay of telemetry, command answers and streamed setpoints (s)", 0.0, 10.0, 0.2),
    "autopilot_clock_jump": ("jump of the autopilot's timestamps (s)", -3600.0, 3600.0, 10.0),
    "wind_gust": ("gust speed as a fraction of the vehicle's horizontal speed limit", 0.0,
                  1.0, 0.3),
}

COMMANDS = ("arm", "takeoff", "start_offboard", "set_setpoint", "stop_offboard", "hold",
            "land", "return_to_launch", "grab", "release")


class FaultSpec(BaseModel):
    """One injected fault."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    kind: FaultKind
    at_s: float | None = Field(None, ge=0, description="mission time of the injection (s)")
    at_state: MissionStateName | None = Field(
        None, description="inject when the mission enters this state (+ delay_s)")
    delay_s: float = Field(0.0, ge=0, description="after entering at_state (s)")
    duration_s: float = Field(1.0, gt=0, le=3600,
                              description="how long the fault lasts (s); corrupted/"
                                          "truncated frames: every frame grabbed in it, at "
                                          "least one; device loss, clock "
                                          "jumps (camera and autopilot) and a battery "
                                          "drain last to the end")
    size: float | None = Field(None, description="the fault's size (unit per kind, "
                                                 "docs/faults.md); None: the kind's default")
    camera: Literal["wide", "narrow", "both"] = Field(
        "both", description="camera faults: which camera")
    command: str = Field("set_setpoint", description="command_denied: the refused command")
    direction_deg: float = Field(90.0, description="wind_gust: direction it blows towards "
                                                   "(deg from north)")

    @model_validator(mode="after")
    def _check(self) -> FaultSpec:
        if (self.at_s is None) == (self.at_state is None):
            raise ValueError("give exactly one of at_s and at_state")
        if self.at_s is not None and self.delay_s:
            raise ValueError("delay_s goes with at_state, not at_s")
        if self.size is not None:
            if self.kind not in SIZES:
                raise ValueError(f"size: {self.kind} takes no size")
            what, lo, hi, _ = SIZES[self.kind]
            if not lo < self.size <= hi:
                raise ValueError(f"size: {what} must be in ({lo:g}, {hi:g}], got {self.size:g}")
        if self.command not in COMMANDS:
            raise ValueError(f"command: must be one of {', '.join(COMMANDS)}, "
                             f"got {self.command!r}")
        return self

    @property
    def value(self) -> float:
        """``size`` or the kind's default (0 for kinds without a size)."""
        if self.size is not None:
            return self.size
        return SIZES[self.kind][3] if self.kind in SIZES else 0.0


class FaultsConfig(BaseModel):
    """``faults:``: what to inject, and the bound on wind gusts."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    inject: list[FaultSpec] = Field(default_factory=list)
    max_gust_fraction: float = Field(
        0.5, gt=0, le=1, description="largest wind_gust size allowed, as a fraction of the "
                                     "vehicle's horizontal speed limit (its authority)")

    @model_validator(mode="after")
    def _gusts_bounded(self) -> FaultsConfig:
        for i, f in enumerate(self.inject):
            if f.kind == "wind_gust" and f.value > self.max_gust_fraction:
                raise ValueError(f"inject[{i}].size: a gust of {f.value:g} of the vehicle's "
                                 f"authority exceeds max_gust_fraction "
                                 f"{self.max_gust_fraction:g}")
        return self


def faults_of(mission_file: Any) -> FaultsConfig | None:
    """The validated ``faults:`` section of a mission file (None without one)."""
    raw = getattr(mission_file, "faults", None)
    return None if raw is None else FaultsConfig.model_validate(raw)
