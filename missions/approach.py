"""The approach-to-grasp mission (paper Sec. 3.2, Figs. 4 and 14) as a state machine.

States are an :class:`MissionState` enum and every transition lives in ONE table,
:data:`TRANSITIONS`, built with ``transitions`` (``auto_transitions=False``: no ``to_<state>()``
can bypass a guard). Guards are pure predicates on a frozen :class:`Snapshot` that the runner
assembles from telemetry, perception and the filter; per-state timeouts come from
``mission.timeouts``; ``abort`` is allowed from every non-final state and carries the reason
and the configured safe action.

Design choice (STYLE.md item 13): the machine is the synchronous ``transitions.Machine``,
stepped by the runner's control task on the mission clock, not an ``AsyncMachine``.
AsyncMachine cancels running callbacks when a new event arrives (transitions #465, #474, #713);
here every callback is O(1) bookkeeping and all vehicle commands (arm, takeoff, offboard, land,
return, grab) run in the runner's actuator task, so nothing long runs inside the machine, and
state timeouts are plain guards on ``Snapshot.time_in_state_s`` -- deterministic under the
virtual-time loop.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from eaglemission.missions.filter import FilterConfig
from pydantic import BaseModel, ConfigDict, Field
from transitions import Machine

log = logging.getLogger(__name__)

SafeAction = Literal["hold", "return", "land"]
FinalAction = Literal["hold", "return", "land", "release", "none"]


class MissionState(enum.Enum):
    """States of the approach-to-grasp mission."""

    PREFLIGHT = "PREFLIGHT"
    TAKEOFF = "TAKEOFF"
    CRUISE = "CRUISE"
    COARSE_APPROACH = "COARSE_APPROACH"
    FINE_APPROACH = "FINE_APPROACH"
    GRASP_READY = "GRASP_READY"
    TARGET_LOST = "TARGET_LOST"
    DONE = "DONE"
    FAILSAFE = "FAILSAFE"


S = MissionState
FINAL_STATES = frozenset({S.DONE, S.FAILSAFE})
ACTIVE_STATES = tuple(s for s in S if s not in FINAL_STATES)
AIRBORNE_STATES = frozenset({S.TAKEOFF, S.CRUISE, S.COARSE_APPROACH, S.FINE_APPROACH,
                             S.GRASP_READY, S.TARGET_LOST})
OFFBOARD_STATES = frozenset({S.CRUISE, S.COARSE_APPROACH, S.FINE_APPROACH, S.GRASP_READY,
                             S.TARGET_LOST})
TIMEOUT_FIELD = {S.PREFLIGHT: "preflight_s", S.TAKEOFF: "takeoff_s", S.CRUISE: "cruise_s",
                 S.COARSE_APPROACH: "coarse_approach_s", S.FINE_APPROACH: "fine_approach_s",
                 S.GRASP_READY: "grasp_ready_s", S.TARGET_LOST: "target_lost_s"}


class ApproachConfig(BaseModel):
    """Extra parameters of the ``approach`` mission (``mission.params``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    process_rate_hz: float = Field(8.0, gt=0, le=200,
                                   description="frames processed per second per active camera")
    detector_downscale: int = Field(2, ge=1, le=8,
                                    description="detector works at 1/k resolution when it offers "
                                                "`downscale`")
    narrow_threshold: Literal["config", "otsu", "mean"] = Field(
        "config", description="threshold of the narrow camera's detector: the paper's "
        "'adaptive threshold segmentation' (otsu / mean) or the detector config's")
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
    colour_tolerance: float = Field(0.25, gt=0, le=2, description="L1 chromaticity distance")
    yaw_rate_degps: float = Field(45.0, gt=0, description="yaw rate of the setpoints")
    search_radius_m: float = Field(2.0, ge=0, description="TARGET_LOST search circle radius")
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


# ---------------------------------------------------------------------------------------------
# Snapshot and pure guards
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Snapshot:
    """Everything a guard may look at, frozen at one control tick (units in the names)."""

    t_s: float = 0.0
    time_in_state_s: float = 0.0
    state_timeout_s: float = float("inf")
    # preflight
    armable: bool = False
    position_valid: bool = False
    cameras_streaming: bool = False
    detector_warm: bool = False
    telemetry_hz: float = 0.0
    min_telemetry_hz: float = 10.0
    # flight
    in_air: bool = False
    altitude_m: float = 0.0
    takeoff_altitude_m: float = 0.0
    takeoff_tolerance_m: float = 0.3
    route_finished: bool = False
    # perception
    confirmed_frames: int = 0
    confirm_frames: int = 3
    target_in_narrow_view: bool = False
    narrow_warm: bool = False
    has_target: bool = False
    target_age_s: float = float("inf")
    target_expected_visible: bool = True
    target_lost_after_s: float = 2.5
    # grasp
    grasp_stable_frames: int = 0
    grasp_required_frames: int = 5
    grasp_done: bool = False
    search_exhausted: bool = False
    on_target_lost: str = "resume_cruise"
    # faults (the runner fills them from telemetry, the cameras and the envelope)
    link_lost_s: float = 0.0
    link_loss_timeout_s: float = 1.5
    gps_ok: bool = True
    battery_remaining: float = 1.0
    low_battery_fraction: float = 0.2
    goal_inside_geofence: bool = True
    camera_failed: bool = False
    pilot_override: bool = False
    command_failed: str = ""
    interrupt_reason: str = ""
    """The operator asked for a stop (Ctrl-C / SIGTERM): the reason, "" if not."""
    interrupt_action: str = "return"
    extra: dict[str, Any] = field(default_factory=dict)


def preflight_ok(s: Snapshot) -> bool:
    """Armable with a valid position, both cameras streaming, detector warm, telemetry fast."""
    return (s.armable and s.position_valid and s.cameras_streaming and s.detector_warm
            and s.telemetry_hz >= s.min_telemetry_hz)


def takeoff_done(s: Snapshot) -> bool:
    return s.in_air and s.altitude_m >= s.takeoff_altitude_m - s.takeoff_tolerance_m


def target_confirmed(s: Snapshot) -> bool:
    """Wide-camera detections agreeing over ``confirm_frames`` consecutive frames."""
    return s.confirmed_frames >= s.confirm_frames


def narrow_ready(s: Snapshot) -> bool:
    """The target lies inside the narrow camera's view (in the wide image) and the narrow
    detector is warm."""
    return s.target_in_narrow_view and s.narrow_warm and s.has_target


def grasp_stable(s: Snapshot) -> bool:
    return s.grasp_stable_frames >= s.grasp_required_frames


def grasp_finished(s: Snapshot) -> bool:
    return s.grasp_done


def target_lost(s: Snapshot) -> bool:
    """No usable estimate for ``target_lost_after_s`` although the target should be in view."""
    return (not s.has_target) or (s.target_expected_visible
                                  and s.target_age_s > s.target_lost_after_s)


def target_reacquired(s: Snapshot) -> bool:
    return s.confirmed_frames >= s.confirm_frames


def lost_resumes_cruise(s: Snapshot) -> bool:
    return s.search_exhausted and s.on_target_lost == "resume_cruise"


def route_finished(s: Snapshot) -> bool:
    return s.route_finished


def state_timed_out(s: Snapshot) -> bool:
    return s.time_in_state_s > s.state_timeout_s


# ---------------------------------------------------------------------------------------------
# The table
# ---------------------------------------------------------------------------------------------
TRANSITIONS: list[dict[str, Any]] = [
    {"trigger": "preflight_passed", "source": S.PREFLIGHT, "dest": S.TAKEOFF,
     "conditions": [preflight_ok]},
    {"trigger": "reached_altitude", "source": S.TAKEOFF, "dest": S.CRUISE,
     "conditions": [takeoff_done]},
    {"trigger": "target_detected", "source": S.CRUISE, "dest": S.COARSE_APPROACH,
     "conditions": [target_confirmed]},
    {"trigger": "in_narrow_view", "source": S.COARSE_APPROACH, "dest": S.FINE_APPROACH,
     "conditions": [narrow_ready]},
    {"trigger": "tool_point_at_grasp", "source": S.FINE_APPROACH, "dest": S.GRASP_READY,
     "conditions": [grasp_stable]},
    {"trigger": "grasp_complete", "source": S.GRASP_READY, "dest": S.DONE,
     "conditions": [grasp_finished]},
    {"trigger": "lost", "source": [S.COARSE_APPROACH, S.FINE_APPROACH, S.GRASP_READY],
     "dest": S.TARGET_LOST, "conditions": [target_lost]},
    {"trigger": "reacquired", "source": S.TARGET_LOST, "dest": S.COARSE_APPROACH,
     "conditions": [target_reacquired]},
    {"trigger": "resume_cruise", "source": S.TARGET_LOST, "dest": S.CRUISE,
     "conditions": [lost_resumes_cruise]},
    {"trigger": "abort", "source": list(ACTIVE_STATES), "dest": S.FAILSAFE},
]
"""THE transition table. ``abort`` (failsafes, timeouts, route end, refused commands) is
fired by :func:`failsafe` with a reason and the configured safe action."""


@dataclass(frozen=True, slots=True)
class Abort:
    reason: str
    action: FinalAction


def failsafe(state: MissionState, s: Snapshot, mission: Any, safety: Any,
             params: ApproachConfig) -> Abort | None:
    """The failsafe that applies in ``state`` (pure; first match in priority order).

    Priority: the operator's interrupt, link loss, GPS loss, low battery, pilot mode change, camera failure, geofence,
    refused command, state timeout, route end without target. On the ground (PREFLIGHT) the
    action is ``none``: the vehicle is never armed.
    """
    if state in FINAL_STATES:
        return None
    on_ground = state is S.PREFLIGHT

    def act(a: FinalAction) -> FinalAction:
        return "none" if on_ground else a

    if s.interrupt_reason:
        return Abort(s.interrupt_reason, act(s.interrupt_action))  # type: ignore[arg-type]
    if s.link_lost_s > s.link_loss_timeout_s and not on_ground:
        return Abort(f"link lost for {s.link_lost_s:.1f} s", act(safety.link_loss_action))
    if not s.gps_ok and not on_ground:
        return Abort("GPS lost", act(safety.gps_loss_action))
    if s.battery_remaining < s.low_battery_fraction:
        return Abort(f"battery low ({s.battery_remaining:.0%})", act(safety.low_battery_action))
    if s.pilot_override:
        return Abort("flight mode changed by the pilot or the autopilot: stop commanding",
                     "release")
    if s.camera_failed:
        return Abort("camera failure: no frames", act(params.camera_failure_action))
    if not s.goal_inside_geofence:
        return Abort("the approach goal lies outside the geofence", act(params.geofence_action))
    if s.command_failed:
        return Abort(f"command failed: {s.command_failed}", act(params.timeout_action))
    if state_timed_out(s):
        if state is S.TARGET_LOST:
            if mission.on_target_lost == "resume_cruise":
                return None  # handled by the resume_cruise transition
            return Abort(f"target lost for {s.time_in_state_s:.1f} s",
                         act(mission.on_target_lost))
        return Abort(f"{state.value} timed out after {s.state_timeout_s:g} s",
                     act(params.timeout_action))
    if state is S.CRUISE and route_finished(s):
        return Abort("route finished without a confirmed target", act(params.route_end_action))
    return None


class ApproachMachine:
    """The model of the ``transitions`` machine. ``step(snapshot)`` fires at most one
    transition; ``on_change`` is called with (old, new, reason) after every state change."""

    def __init__(self, *, on_change: Callable[[MissionState, MissionState, str], None]
                 | None = None) -> None:
        self.state: MissionState = S.PREFLIGHT
        self.reason = ""
        self.action: FinalAction = "none"
        self._on_change = on_change
        self.machine = Machine(model=self, states=MissionState, transitions=TRANSITIONS,
                               initial=S.PREFLIGHT, auto_transitions=False,
                               after_state_change="_after_change", ignore_invalid_triggers=False)
        self._pending: tuple[MissionState, str] | None = None

    # transitions calls this with the trigger's arguments
    def _after_change(self, *args: Any, **kwargs: Any) -> None:
        old = self._pending[0] if self._pending else self.state
        if self._on_change is not None:
            self._on_change(old, self.state, self.reason)

    def _fire(self, trigger: str, *args: Any) -> bool:
        self._pending = (self.state, trigger)
        try:
            return bool(self.trigger(trigger, *args))  # type: ignore[attr-defined]
        finally:
            self._pending = None

    def candidates(self) -> list[str]:
        """Triggers leaving the current state, in table order (abort excluded)."""
        out = []
        for t in TRANSITIONS:
            src = t["source"] if isinstance(t["source"], list) else [t["source"]]
            if self.state in src and t["trigger"] != "abort":
                out.append(t["trigger"])
        return out

    def step(self, snap: Snapshot, abort: Abort | None = None) -> str | None:
        """Fire the abort if given, else the first guarded transition that holds."""
        if self.state in FINAL_STATES:
            return None
        if abort is not None:
            self.reason, self.action = abort.reason, abort.action
            self._fire("abort")
            return "abort"
        for trig in self.candidates():
            prev = self.reason
            self.reason = trig
            if self._fire(trig, snap):
                return trig
            self.reason = prev
        return None

    @property
    def final(self) -> bool:
        return self.state in FINAL_STATES


def mermaid_diagram() -> str:
    """The machine as a Mermaid ``stateDiagram-v2`` (transitions' mermaid engine, no graphviz)."""
    from transitions.extensions.diagrams import GraphMachine

    class _Model:
        pass

    model = _Model()
    GraphMachine(model=model, states=MissionState, transitions=TRANSITIONS,
                 initial=S.PREFLIGHT, auto_transitions=False, graph_engine="mermaid",
                 show_conditions=True, title="approach mission")
    text = model.get_graph().draw(None)  # type: ignore[attr-defined]
    return "\n".join(line.rstrip() for line in text.splitlines()).strip() + "\n"


if __name__ == "__main__":  # regenerate the diagram: python -m eaglemission.missions.approach
    import sys

    sys.stdout.write(mermaid_diagram())
