"""Parameters of the ``approach`` mission (``mission.params``): speeds, confirmation, grasp
band, standoff, per-state timeouts, safe actions and the target filter."""

from __future__ import annotations

from typing import Annotated, Literal

from eaglemission.missions.target_state import FilterConfig
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.config import MissionFile, SafeAction, StrictModel

_Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class StandoffConfig(StrictModel):
    """Where the vehicle waits for the grasp, relative to the target's top-face centre: a
    horizontal offset (along the approach direction) and a height, so the fixed, tilted
    cameras still see the target."""

    horizontal_m: _NonNeg = 2.5
    height_m: _Pos = 1.5


class TimeoutsConfig(StrictModel):
    preflight_s: _Pos = 30.0
    takeoff_s: _Pos = 60.0
    cruise_s: _Pos = 600.0
    coarse_approach_s: _Pos = 120.0
    fine_approach_s: _Pos = 120.0
    grasp_ready_s: _Pos = 30.0
    target_lost_s: _Pos = 20.0
    command_s: _Pos = 10.0


class ApproachConfig(BaseModel):
    """Extra parameters of the ``approach`` mission (``mission.params``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    approach_speed_mps: _Pos = Field(1.0, description="coarse approach and standoff speed")
    confirm_frames: Annotated[int, Field(ge=1, le=1000)] = Field(
        3, description="consecutive agreeing wide-camera estimates that confirm the target")
    grasp_distance_m: Annotated[float, Field(gt=0, le=2.0)] = Field(
        0.175, description="height of the tool point above the target's top at the grasp pose")
    grasp_tolerance_m: Annotated[float, Field(gt=0, le=1.0)] = 0.05
    grasp_stable_frames: Annotated[int, Field(ge=1, le=1000)] = 5
    standoff: StandoffConfig = Field(default_factory=StandoffConfig)
    timeouts: TimeoutsConfig = Field(default_factory=TimeoutsConfig)
    on_target_lost: Literal["resume_cruise", "return", "land", "hold"] = "resume_cruise"
    on_done: Literal["land", "return", "hold"] = "land"
    grasp_action: Literal["gripper", "callback", "none"] = "gripper"
    setpoint_rate_hz: Annotated[float, Field(ge=10, le=100)] = 20.0
    process_rate_hz: float = Field(8.0, gt=0, le=200,
                                   description="frames processed per second per active camera")
    narrow_warmup_frames: int = Field(4, ge=0, le=100,
                                      description="narrow-camera frames run through the detector "
                                                  "before its output is used")
    warm_margin_px: float = Field(150.0, ge=0, description="start warming the narrow detector "
                                  "when the target is this close (wide px) to its view")
    confirm_radius_m: float = Field(3.0, gt=0, description="wide estimates agreeing within this "
                                    "radius count towards mission.confirm_frames")
    target_lost_after_s: float = Field(2.5, gt=0, description="no usable estimate for this long "
                                       "while the target should be visible -> TARGET_LOST")
    camera_failure_after_s: float = Field(2.0, gt=0, description="no frame from a needed camera "
                                          "for this long -> camera failure")
    fine_standoff_tolerance_m: float = Field(0.3, gt=0, description="at the standoff within this "
                                             "distance before descending to the grasp pose")
    fine_min_estimates: int = Field(5, ge=1, description="fine estimates fused before leaving "
                                    "the standoff")
    standoff_max_wait_s: float = Field(3.0, gt=0, description="descend from the standoff after "
                                       "this long even with fewer fine estimates (the filter "
                                       "holds the coarse ones)")
    final_speed_mps: float = Field(0.4, gt=0, description="speed from the standoff to the grasp "
                                   "pose")
    narrow_max_fill: float = Field(0.6, gt=0, le=1, description="switch back to the wide camera "
                                   "when the target spans more than this fraction of the narrow "
                                   "image (or leaves it)")
    narrow_miss_switch_s: float = Field(1.0, gt=0, description="fine approach: continue with "
                                        "the wide camera when the narrow one gives no fine "
                                        "estimate for this long")
    min_estimate_range_m: float = Field(0.5, ge=0, description="estimates of a target closer "
                                        "than this to the camera are not used (it no longer "
                                        "fits the view; the filter holds the last position)")
    fallback_std_factor: float = Field(3.0, ge=1, description="weight of a coarse estimate "
                                       "used when the fine estimator refuses a detection")
    image_border_px: float = Field(4.0, ge=0, description="detections touching this border are "
                                   "truncated and not used for estimation")
    size_ratio_range: tuple[float, float] = Field(
        (0.2, 5.0), description="accepted detection area / area expected from the camera pose "
        "and the target's size (paper: MBR filtered by the target's size and aspect)")
    colour_check: bool = Field(True, description="when target.color_bgr is set, a detection's "
                               "core must have the target's chromaticity (not in the paper)")
    yaw_rate_degps: float = Field(45.0, gt=0, description="yaw rate of the setpoints")
    search_radius_m: float = Field(2.0, ge=0, description="TARGET_LOST search circle radius")
    max_target_losses: int = Field(3, ge=1, le=1000, description="the target lost this many "
                                   "times near one place rejects that candidate: its estimates "
                                   "are ignored and `on_target_lost` applies at once (a "
                                   "distractor the fine approach keeps refusing; not in the "
                                   "paper)")
    max_route_passes: int = Field(2, ge=1, le=10, description="a rejected candidate sends "
                                  "the search along the route again from its start once it "
                                  "ends (the target may have been passed unconfirmed), up to "
                                  "this many passes in all (not in the paper)")
    heading_min_consistency: float = Field(
        0.0, ge=0, le=1, description="an elongated target's fitted heading must agree across "
        "its complete close-range views: below this mean resultant length of the doubled "
        "headings (1 = all agree, 0 = spread evenly) the candidate is rejected as not the "
        "target's shape (a same-coloured box of the target's area; 0, the default, disables it; "
        "0.6 rejects campaign run 521's box but also 11 of 762 true targets: docs/mission.md, "
        "\"candidate rejection\"; not in the paper)")
    heading_min_views: int = Field(12, ge=2, description="complete close-range views before "
                                   "heading_min_consistency is judged")
    silhouette_min_iou: float | None = Field(
        0.86, gt=0, lt=1, description="the candidate's outlines must fit the target's shape: "
        "below this median IoU of its complete close-range views (outline at least 30 px "
        "across) with the target's projected top face or box (best heading) the candidate is "
        "rejected as not the target (a box of its colour and top area but another shape; needs "
        "target.color_bgr: the outline is the colour region's; null disables it; "
        "docs/mission.md, \"candidate rejection by shape\"; not in the paper)")
    silhouette_min_views: int = Field(8, ge=1, description="complete close-range views "
                                      "before silhouette_min_iou is judged")
    silhouette_heading_min_iou: float = Field(
        0.86, gt=0, le=1, description="a complete close view whose colour outline fits the "
        "target at least this well gives the heading the views cut by the image border are "
        "fitted around (the outline's heading, within a few degrees; else the plane fit's on "
        "its 15 deg grid; docs/mission.md; not in the paper)")
    takeoff_tolerance_m: float = Field(0.3, gt=0)
    min_telemetry_hz: float = Field(10.0, gt=0)
    vertical_reference: Literal["ground", "estimate", "hybrid"] = Field(
        "hybrid", description="range of the target: `ground` = the estimate's direction meets "
        "the plane of the target's top (flat ground at home's height, docs/conventions.md), "
        "`estimate` = the estimators' 3-D value, `hybrid` = ground beyond full_3d_range_m")
    full_3d_range_m: float = Field(1.6, gt=0, description="hybrid: closer than this, use the "
                                   "full 3-D PnP estimate")
    plane_fit: bool = Field(True, description="replace a detection's position by the fit of "
                            "the target's top face or box silhouette on the plane of its top "
                            "(missions/silhouette.py; not in the paper)")
    plane_fit_max_cost: float = Field(0.4, gt=0, description="final approach: refuse a "
                                      "detection whose MBR side lengths no region model "
                                      "explains (sum of |log ratio|)")
    plane_fit_angular_std_deg: float = Field(1.0, gt=0, description="1-sigma angular error of "
                                             "a plane-fit estimate (mount, attitude, pixels)")
    grasp_accept_fraction: float = Field(0.5, gt=0, le=1, description="GRASP_READY needs the "
                                         "running mean of the estimated tool-point errors within "
                                         "this fraction of the tolerance (margin for the "
                                         "estimate's own error)")
    grasp_hold_factor: float = Field(1.6, ge=1, description="grasp stability: every frame "
                                     "within this x grasp_tolerance_m, their mean within it "
                                     "(a hover in wind jitters by a few cm)")
    colour_track: bool = Field(True, description="final approach: when the detector gives no "
                               "usable region, take the region of the target's colour near "
                               "the predicted pixel (needs target.color_bgr; not in the paper)")
    size_range: bool = Field(True, description="final approach: fuse the range from the "
                             "target's apparent size (plane fit) with the plane's range")
    size_std_fraction: float = Field(0.02, gt=0, description="1-sigma relative error of the "
                                     "range from apparent size (focal error, segmentation)")
    altitude_std_m: float = Field(0.04, gt=0, description="1-sigma error of the vehicle's "
                                  "altitude estimate (sets the plane's range error)")
    plane_offset: bool = Field(True, description="track the height of the target's top in "
                               "the vehicle's estimated frame (measured by a downward "
                               "rangefinder, optionally by apparent size) and fit every view on "
                               "that plane, instead of trusting the altitude estimate "
                               "(docs/mission.md)")
    plane_from_size: bool = Field(False, description="also measure the plane from complete "
                                  "close views' apparent size (off: measured worse than the "
                                  "altitude estimate alone, docs/mission.md)")
    rangefinder: Literal["auto", "off"] = Field("auto", description="auto: a downward distance "
                                                "sensor in the telemetry measures the plane")
    rangefinder_std_m: float = Field(0.02, gt=0, description="1-sigma error of a rangefinder "
                                     "reading, ground roughness included")
    plane_max_cost: float = Field(0.2, gt=0, description="only views whose plane fit costs "
                                  "at most this measure the plane")
    plane_offset_drift_mps: float = Field(0.01, ge=0, description="random-walk sigma of the "
                                          "altitude estimate's drift, m per sqrt(s)")
    tilt_compensation: bool = Field(True, description="place the tool point over the target "
                                    "at the vehicle's current (low-passed) attitude: in wind the "
                                    "vehicle leans and a level-attitude goal is off by cm")
    grasp_max_speed_mps: float = Field(0.1, gt=0, description="grasp stability counts only "
                                       "frames with the vehicle slower than this")
    grasp_trim_gain_per_s: float = Field(0.5, ge=0, description="integral trim of the "
                                         "setpoint at the grasp pose (steady wind offset); 0 = "
                                         "off")
    grasp_trim_max_m: float = Field(0.15, ge=0, description="largest trim")
    geofence_action: SafeAction = "return"
    camera_failure_action: SafeAction = "return"
    timeout_action: SafeAction = "return"
    route_end_action: SafeAction = "return"
    settle_timeout_s: float = Field(180.0, gt=0, description="after DONE/FAILSAFE, wait this "
                                    "long for the vehicle to land (sim: evaluates the return)")
    filter: FilterConfig = Field(default_factory=FilterConfig)

    @classmethod
    def of(cls, cfg: MissionFile) -> ApproachConfig:
        """The approach parameters of a mission file (``mission.params``, validated)."""
        return cls.model_validate(dict(cfg.mission.params))
