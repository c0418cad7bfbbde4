"""Parameters of the ``approach`` mission (``mission.params``), grouped by concern.

``guidance`` (speeds, standoff, trim, route passes), ``perception`` (how a frame becomes a
measurement of the target), ``tracking`` (confirmation, the target filter, loss, candidate
rejection), ``plane`` (the target's top plane), ``grasp``, ``actions`` (safe actions and the end
of the flight) and ``timeouts``. Every key has a default that flies: a mission file may leave any
of them out. The mechanisms marked "not in the paper" are described in docs/mission.md.
"""

from __future__ import annotations

from typing import Annotated, Literal

from eaglemission.missions.target_state import FilterConfig
from pydantic import Field

from eaglemission.config import MissionFile, SafeAction, StrictModel

_Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class StandoffConfig(StrictModel):
    """Where the vehicle waits before the descent to the grasp, relative to the target's
    top-face centre (a horizontal offset along the approach direction and a height, so the fixed,
    tilted cameras still see the target), and when it leaves."""

    horizontal_m: _NonNeg = Field(2.5, description="short of the target along the approach "
                                  "direction")
    height_m: _Pos = Field(1.5, description="above the target's top face")
    tolerance_m: _Pos = Field(0.3, description="at the standoff within this distance before "
                              "descending to the grasp pose")
    min_fine_estimates: int = Field(5, ge=1, description="fine estimates fused at the standoff "
                                    "before descending")
    max_wait_s: _Pos = Field(3.0, description="descend after this long at the standoff even "
                             "with fewer fine estimates (the filter holds the coarse ones)")


class GuidanceConfig(StrictModel):
    """Where and how fast the setpoints steer: speeds, the standoff, the grasp pose's trim and
    the route's passes."""

    approach_speed_mps: _Pos = Field(1.0, description="coarse approach and standoff speed")
    final_speed_mps: _Pos = Field(0.4, description="speed from the standoff to the grasp pose")
    yaw_rate_degps: _Pos = Field(45.0, description="yaw rate of the setpoints")
    setpoint_rate_hz: Annotated[float, Field(ge=10, le=100)] = Field(
        20.0, description="setpoints sent per second (more often after a fresh estimate)")
    takeoff_tolerance_m: _Pos = Field(0.3, description="TAKEOFF ends within this of the "
                                      "cruise altitude")
    standoff: StandoffConfig = Field(default_factory=StandoffConfig)
    grasp_trim_gain_per_s: _NonNeg = Field(0.5, description="integral trim of the setpoint at "
                                           "the grasp pose (a steady offset in wind); 0 = off")
    grasp_trim_max_m: _NonNeg = Field(0.15, description="largest trim")
    max_route_passes: int = Field(2, ge=1, le=10, description="a rejected candidate sends the "
                                  "search along the route again from its start once it ends "
                                  "(the target may have been passed unconfirmed), up to this "
                                  "many passes in all (not in the paper; docs/mission.md, TARGET_LOST)")


class PerceptionConfig(StrictModel):
    """How a frame becomes a measurement of the target: processing rate, the dual camera's
    hand-over, which detections are plausible, the estimate's weight and range."""

    process_rate_hz: float = Field(8.0, gt=0, le=200,
                                   description="frames processed per second per active camera")
    narrow_warmup_frames: int = Field(4, ge=0, le=100,
                                      description="narrow-camera frames run through the detector "
                                                  "before its output is used")
    narrow_warm_margin_px: _NonNeg = Field(150.0, description="start warming the narrow "
                                           "detector when the target is this close (wide px) to "
                                           "its view")
    narrow_max_fill: float = Field(0.6, gt=0, le=1, description="switch back to the wide camera "
                                   "when the target spans more than this fraction of the narrow "
                                   "image (or leaves it)")
    narrow_miss_switch_s: _Pos = Field(1.0, description="fine approach: continue with the wide "
                                       "camera when the narrow one gives no fine estimate for "
                                       "this long")
    image_border_px: _NonNeg = Field(4.0, description="detections touching this border are "
                                     "truncated and not used for estimation")
    size_ratio_range: tuple[float, float] = Field(
        (0.2, 5.0), description="accepted detection area / area expected from the camera pose "
        "and the target's size (paper: MBR filtered by the target's size and aspect)")
    min_estimate_range_m: _NonNeg = Field(0.5, description="estimates of a target closer than "
                                          "this to the camera are not used (it no longer fits "
                                          "the view; the filter holds the last position)")
    fallback_std_factor: float = Field(3.0, ge=1, description="weight of a coarse estimate "
                                       "used when the fine estimator refuses a detection")
    plane_fit_max_cost: _Pos = Field(0.4, description="final approach: refuse a detection "
                                     "whose MBR side lengths no region model of the plane fit "
                                     "explains (sum of |log ratio|)")
    plane_fit_angular_std_deg: _Pos = Field(1.0, description="1-sigma angular error of a "
                                            "plane-fit position (mount, attitude, pixels)")
    size_std_fraction: _Pos = Field(0.02, description="final approach: 1-sigma relative error "
                                    "of the range from the target's apparent size (focal "
                                    "error, segmentation), fused with the plane's range")
    silhouette_heading_min_iou: float = Field(
        0.86, gt=0, le=1, description="a complete close view whose colour outline fits the "
        "target at least this well gives the heading the views cut by the image border are "
        "fitted around (the outline's heading, else the plane fit's; needs target.color_bgr; "
        "not in the paper; docs/mission.md, \"The final approach\")")
    silhouette_heading_span_deg: float | None = Field(
        None, gt=0, le=90, description="a view cut by the image border is fitted within +- "
        "this of a heading the outline gave (null: +- the fitter's step, 15 deg). 3 deg, one "
        "step of the outline's grid: 37 instead of 28 of 50 arm grasps within 2.5 cm in gusts, "
        "but 46 instead of 49 of 50 in the seed-7 campaign (reports/mission_campaigns.md)")
    vertical_reference: Literal["ground", "estimate", "hybrid"] = Field(
        "hybrid", description="range of the target: `ground` = the estimate's direction meets "
        "the plane of the target's top (flat ground at home's height, docs/conventions.md), "
        "`estimate` = the estimators' 3-D value, `hybrid` = ground beyond full_3d_range_m")
    full_3d_range_m: _Pos = Field(1.6, description="hybrid: closer than this, use the full 3-D "
                                  "estimate")


class ShapeCheckConfig(StrictModel):
    """The candidate's colour outlines must fit the target's shape (a box of the target's
    colour and top area but another shape is rejected; needs target.color_bgr; not in the
    paper; docs/mission.md, "Candidate rejection by shape")."""

    min_iou: float | None = Field(
        0.86, gt=0, lt=1, description="below this median IoU of the candidate's complete "
        "close-range views (outline at least 30 px across) with the target's projected top "
        "face or box (best heading), the candidate is rejected; null: no shape check")
    min_views: int = Field(8, ge=1, description="complete close-range views before min_iou "
                           "is judged")


class TrackingConfig(StrictModel):
    """The target as the mission follows it: the wide camera's confirmation, the position
    filter, when it counts as lost and when a candidate is rejected."""

    confirm_frames: Annotated[int, Field(ge=1, le=1000)] = Field(
        3, description="consecutive agreeing wide-camera estimates that confirm the target")
    confirm_radius_m: _Pos = Field(3.0, description="wide estimates agreeing within this "
                                   "radius count towards confirm_frames")
    lost_after_s: _Pos = Field(2.5, description="no usable estimate for this long while the "
                               "target should be visible -> TARGET_LOST")
    reacquire_radius_m: _NonNeg = Field(2.0, description="TARGET_LOST: wide estimates count "
                                        "towards reacquisition only within this distance plus "
                                        "confirm_radius_m of where the target was last tracked; "
                                        "losses that close count as one place")
    max_losses: int = Field(3, ge=1, le=1000, description="the target lost this many times near "
                            "one place rejects that candidate: its estimates are ignored and "
                            "actions.on_target_lost applies at once (a distractor the fine "
                            "approach keeps refusing; not in the paper; docs/mission.md, "
                            "failsafes)")
    shape: ShapeCheckConfig = Field(default_factory=ShapeCheckConfig)
    filter: FilterConfig = Field(default_factory=FilterConfig)


class PlaneConfig(StrictModel):
    """The height of the target's top plane in the vehicle's estimated frame, measured by a
    downward rangefinder when the telemetry carries one (not in the paper; docs/mission.md,
    "the target's plane")."""

    rangefinder: Literal["auto", "off"] = Field("auto", description="auto: a downward distance "
                                                "sensor in the telemetry measures the plane; "
                                                "off: the plane stays at home's height")
    rangefinder_std_m: _Pos = Field(0.02, description="1-sigma error of a rangefinder reading, "
                                    "ground roughness included")
    altitude_std_m: _Pos = Field(0.04, description="1-sigma error of the vehicle's altitude "
                                 "estimate (the plane's prior)")
    drift_mps: _NonNeg = Field(0.01, description="random-walk sigma of the altitude estimate's "
                               "drift, m per sqrt(s)")


class GraspConfig(StrictModel):
    """The grasp pose and when the vehicle is stable there."""

    distance_m: Annotated[float, Field(gt=0, le=2.0)] = Field(
        0.175, description="height of the tool point above the target's top at the grasp pose")
    tolerance_m: Annotated[float, Field(gt=0, le=1.0)] = Field(
        0.05, description="the tool point within this of the grasp pose counts as there")
    stable_frames: Annotated[int, Field(ge=1, le=1000)] = Field(
        5, description="processed frames the tool point must stay there before GRASP_READY")
    accept_fraction: float = Field(0.5, gt=0, le=1, description="GRASP_READY needs the running "
                                   "mean of the estimated tool-point errors within this "
                                   "fraction of the tolerance (margin for the estimate's own "
                                   "error)")
    hold_factor: float = Field(1.6, ge=1, description="every counted frame within this x "
                               "tolerance_m, their mean within it (a hover in wind jitters by "
                               "a few cm)")
    max_speed_mps: _Pos = Field(0.1, description="only frames with the vehicle slower than "
                                "this count")
    action: Literal["gripper", "callback", "none"] = Field(
        "gripper", description="in GRASP_READY: close the vehicle's gripper, await the user's "
        "callback, or nothing")


class ActionsConfig(StrictModel):
    """What the vehicle does when the mission ends or a failsafe fires (the safety section's
    own actions cover link, GPS and battery)."""

    on_target_lost: Literal["resume_cruise", "return", "land", "hold"] = Field(
        "resume_cruise", description="TARGET_LOST timed out, or a candidate rejected")
    on_done: Literal["land", "return", "hold"] = Field("land", description="after the grasp")
    on_geofence: SafeAction = Field("return", description="the approach goal lies outside the "
                                    "geofence")
    on_camera_failure: SafeAction = Field("return", description="a needed camera delivers no "
                                          "frame for timeouts.camera_failure_s")
    on_timeout: SafeAction = Field("return", description="a state timed out, a command was "
                                   "refused, or the offboard watchdog commanded HOLD")
    on_route_end: SafeAction = Field("return", description="the route ended without a "
                                     "confirmed target")


class TimeoutsConfig(StrictModel):
    """How long each state, command and wait may take, and the link's minimum rate."""

    preflight_s: _Pos = 30.0
    takeoff_s: _Pos = 60.0
    cruise_s: _Pos = 600.0
    coarse_approach_s: _Pos = 120.0
    fine_approach_s: _Pos = Field(120.0, description="the fine approach and the descent "
                                  "together")
    grasp_ready_s: _Pos = 30.0
    target_lost_s: _Pos = Field(20.0, description="the search in TARGET_LOST")
    command_s: _Pos = Field(10.0, description="each vehicle command")
    camera_failure_s: _Pos = Field(2.0, description="no frame from a needed camera for this "
                                   "long -> camera failure")
    settle_s: _Pos = Field(180.0, description="after DONE/FAILSAFE, wait this long for the "
                           "vehicle to land (simulation: the evaluator sees the return)")
    min_telemetry_hz: _Pos = Field(10.0, description="PREFLIGHT waits for telemetry at least "
                                   "this fast")


class ApproachConfig(StrictModel):
    """Parameters of the ``approach`` mission (``mission.params``), by concern."""

    guidance: GuidanceConfig = Field(default_factory=GuidanceConfig)
    perception: PerceptionConfig = Field(default_factory=PerceptionConfig)
    tracking: TrackingConfig = Field(default_factory=TrackingConfig)
    plane: PlaneConfig = Field(default_factory=PlaneConfig)
    grasp: GraspConfig = Field(default_factory=GraspConfig)
    actions: ActionsConfig = Field(default_factory=ActionsConfig)
    timeouts: TimeoutsConfig = Field(default_factory=TimeoutsConfig)

    @classmethod
    def of(cls, cfg: MissionFile) -> ApproachConfig:
        """The approach parameters of a mission file (``mission.params``, validated)."""
        return cls.model_validate(dict(cfg.mission.params))
