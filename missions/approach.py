"""The approach-to-grasp mission (paper Sec. 3.2, Figs. 4 and 14) as a state machine.

States are an :class:`MissionState` enum and every transition lives in ONE table,
:data:`TRANSITIONS`, built with ``transitions`` (``auto_transitions=False``: no ``to_<state>()``
can bypass a guard). Guards are pure predicates on a frozen :class:`Snapshot` that the runner
assembles from telemetry, perception and the filter; per-state timeouts come from
``mission.params.timeouts``; ``abort`` is allowed from every non-final state and carries the
reason and the configured safe action.

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

from eaglemission.missions.approach_config import ActionsConfig
from transitions import Machine

from eaglemission.config import SafetyConfig

log = logging.getLogger(__name__)

FinalAction = Literal["hold", "return", "land", "release", "none"]
FINAL_ACTIONS: tuple[FinalAction, ...] = ("hold", "return", "land", "release", "none")


def final_action(name: str) -> FinalAction:
    """``name`` as a :data:`FinalAction`; ValueError naming the allowed ones otherwise."""
    for a in FINAL_ACTIONS:
        if a == name:
            return a
    raise ValueError(f"action: must be one of {', '.join(FINAL_ACTIONS)}, got {name!r}")


class MissionState(enum.Enum):
    """States of the approach-to-grasp mission."""

    PREFLIGHT = "PREFLIGHT"
    TAKEOFF = "TAKEOFF"
    CRUISE = "CRUISE"
    COARSE_APPROACH = "COARSE_APPROACH"
    FINE_APPROACH = "FINE_APPROACH"
    """Fine approach, first part: hold the standoff while the narrow camera's fine estimates
    come in (paper Sec. 3.2: the deep fovea measures)."""
    FINE_DESCENT = "FINE_DESCENT"
    """Fine approach, second part: descend from the standoff to the grasp pose."""
    GRASP_READY = "GRASP_READY"
    TARGET_LOST = "TARGET_LOST"
    DONE = "DONE"
    FAILSAFE = "FAILSAFE"


S = MissionState
FINAL_STATES = frozenset({S.DONE, S.FAILSAFE})
ACTIVE_STATES = tuple(s for s in S if s not in FINAL_STATES)


class Cameras(enum.Enum):
    """Which cameras a state grabs (the paper's cruise uses only the wide camera)."""

    NONE = "none"
    BOTH = "both"
    WIDE = "wide"
    WIDE_WARMING_NARROW = "wide + narrow once the target nears its view"
    FINE = "the fine-approach camera (narrow, or wide when the narrow cannot serve)"


class Goal(enum.Enum):
    """What the setpoints steer to in a state (:mod:`~eaglemission.missions.guidance`)."""

    NONE = "none"
    ROUTE = "the cruise route"
    SEARCH = "a yaw sweep where the target was last seen"
    APPROACH = "the standoff before the target, heading towards it"
    STANDOFF = "the standoff, holding the heading the fine approach started with"
    GRASP = "the grasp pose over the target"


@dataclass(frozen=True, slots=True)
class StatePolicy:
    """What the runner does in one state: data, so that no code outside this table branches on
    the mission state."""

    cameras: Cameras = Cameras.NONE
    estimator: Literal["coarse", "fine", None] = None
    """The wide camera's frames go to the coarse estimator, the fine camera's to the fine."""
    goal: Goal = Goal.NONE
    offboard: bool = False
    """Our setpoints fly the vehicle (a flight-mode change by anyone else is a pilot override)."""
    airborne: bool = False
    confirms: bool = False
    """Wide-camera estimates count towards ``tracking.confirm_frames``."""
    reacquires: bool = False
    """Confirmation counts only estimates near where the target was lost."""
    tracks: bool = False
    """Estimates feed the target filter."""
    filter_may_reset: bool = False
    """A far-off estimate may restart the filter (coarse approach only)."""
    predicts: bool = False
    """Detections are gated around the filter's predicted pixel."""
    close_range: bool = False
    """Fine approach: cut views, colour tracking, strict plane fits."""
    camera_choice: Literal["coarse", "fine", None] = None
    tool_errors: bool = False
    """The mission's own tool-point errors are computed (fine approach on)."""
    grasp_check: bool = False
    """Tool-point stability is counted towards ``grasp.stable_frames``."""
    trim: bool = False
    """The grasp pose's integral trim runs."""
    arm_tracks: bool = False
    """An arm that moves the tool tracks the grasp point until the gripper closes."""
    rangefinder: bool = False
    """Downward rangefinder readings measure the target's plane."""
    camera_watch: bool = False
    """A needed camera that stops delivering is a camera failure."""
    timeout_field: str | None = None
    """``mission.params.timeouts`` field bounding the state."""
    timeout_from: MissionState | None = None
    """The state's timer runs from this state's entry (the fine approach is one budget)."""
    on_enter: tuple[str, ...] = ()
    """Runner actions on entry, in order (see ``MissionRunner`` ``_enter_*``)."""


POLICIES: dict[MissionState, StatePolicy] = {
    S.PREFLIGHT: StatePolicy(cameras=Cameras.BOTH, timeout_field="preflight_s"),
    S.TAKEOFF: StatePolicy(airborne=True, camera_watch=True, timeout_field="takeoff_s",
                           on_enter=("arm_takeoff",)),
    S.CRUISE: StatePolicy(cameras=Cameras.WIDE, estimator="coarse", goal=Goal.ROUTE,
                          offboard=True, airborne=True, confirms=True, camera_watch=True,
                          timeout_field="cruise_s",
                          on_enter=("clear_confirmation", "start_offboard", "route_progress",
                                    "report_rangefinder")),
    S.COARSE_APPROACH: StatePolicy(
        cameras=Cameras.WIDE_WARMING_NARROW, estimator="coarse", goal=Goal.APPROACH,
        offboard=True, airborne=True, tracks=True, filter_may_reset=True, predicts=True,
        camera_choice="coarse", rangefinder=True, camera_watch=True,
        timeout_field="coarse_approach_s", on_enter=("seed_filter",)),
    S.FINE_APPROACH: StatePolicy(
        cameras=Cameras.FINE, estimator="fine", goal=Goal.STANDOFF, offboard=True,
        airborne=True, tracks=True, predicts=True, close_range=True, camera_choice="fine",
        tool_errors=True, rangefinder=True, camera_watch=True, timeout_field="fine_approach_s",
        on_enter=("start_fine",)),
    S.FINE_DESCENT: StatePolicy(
        cameras=Cameras.FINE, estimator="fine", goal=Goal.GRASP, offboard=True, airborne=True,
        tracks=True, predicts=True, close_range=True, camera_choice="fine", tool_errors=True,
        grasp_check=True, trim=True, rangefinder=True, camera_watch=True,
        timeout_field="fine_approach_s", timeout_from=S.FINE_APPROACH),
    S.GRASP_READY: StatePolicy(
        cameras=Cameras.FINE, estimator="fine", goal=Goal.GRASP, offboard=True, airborne=True,
        tracks=True, predicts=True, close_range=True, camera_choice="fine", tool_errors=True,
        grasp_check=True, trim=True, arm_tracks=True, rangefinder=True, camera_watch=True,
        timeout_field="grasp_ready_s", on_enter=("grasp",)),
    S.TARGET_LOST: StatePolicy(cameras=Cameras.WIDE, estimator="coarse", goal=Goal.SEARCH,
                               offboard=True, airborne=True, confirms=True, reacquires=True,
                               predicts=True,
                               camera_watch=True, timeout_field="target_lost_s",
                               on_enter=("count_loss", "clear_confirmation",
                                         "hold_carrot")),
    S.DONE: StatePolicy(on_enter=("final_done",)),
    S.FAILSAFE: StatePolicy(on_enter=("final_failsafe",)),
}
"""The per-state policy table; with :data:`TRANSITIONS`, everything state-dependent."""

AIRBORNE_STATES = frozenset(s for s, p in POLICIES.items() if p.airborne)
OFFBOARD_STATES = frozenset(s for s, p in POLICIES.items() if p.offboard)
TIMEOUT_FIELD = {s: p.timeout_field for s, p in POLICIES.items() if p.timeout_field}


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
    # fine approach: standoff, then descent
    at_standoff: bool = False
    standoff_dwell_s: float = 0.0
    standoff_max_wait_s: float = 3.0
    fine_estimates: int = 0
    fine_min_estimates: int = 5
    # grasp
    grasp_stable_frames: int = 0
    grasp_required_frames: int = 5
    grasp_done: bool = False
    search_exhausted: bool = False
    candidate_rejected: bool = False
    """The loss that entered TARGET_LOST was the ``tracking.max_losses``-th near one place, or
    at a candidate of the wrong shape: that candidate is rejected (``TargetTracking``)."""
    target_losses: int = 0
    """Losses counted near the place of the latest one."""
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
    watchdog_hold: str = ""
    """The driver's offboard watchdog commanded HOLD (the mission's setpoints stalled, e.g. the
    companion computer starved of CPU): what it said, "" if it did not."""
    autopilot_failover: str = ""
    """The autopilot acted on its own while the link was down (the vehicle's ``failover``
    event, e.g. PX4's offboard loss): what it did, "" if nothing."""
    command_failed: str = ""
    interrupt_reason: str = ""
    """The operator asked for a stop (Ctrl-C / SIGTERM): the reason, "" if not."""
    interrupt_action: FinalAction = "return"
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


def ready_to_descend(s: Snapshot) -> bool:
    """At the standoff, with enough fine estimates fused (or after waiting long enough: the
    filter holds the coarse ones)."""
    return s.at_standoff and (s.fine_estimates >= s.fine_min_estimates
                              or s.standoff_dwell_s > s.standoff_max_wait_s)


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
    """The search ran out, or the candidate was rejected: search the route again."""
    return (s.search_exhausted or s.candidate_rejected) and s.on_target_lost == "resume_cruise"


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
    {"trigger": "at_standoff", "source": S.FINE_APPROACH, "dest": S.FINE_DESCENT,
     "conditions": [ready_to_descend]},
    {"trigger": "tool_point_at_grasp", "source": S.FINE_DESCENT, "dest": S.GRASP_READY,
     "conditions": [grasp_stable]},
    {"trigger": "grasp_complete", "source": S.GRASP_READY, "dest": S.DONE,
     "conditions": [grasp_finished]},
    {"trigger": "lost", "source": [S.COARSE_APPROACH, S.FINE_APPROACH, S.FINE_DESCENT,
                                   S.GRASP_READY],
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


def failsafe(state: MissionState, s: Snapshot, safety: SafetyConfig,
             actions: ActionsConfig) -> Abort | None:
    """The failsafe that applies in ``state`` (pure; first match in priority order), with the
    safe actions of ``safety`` and of the mission's ``actions``.

    Priority: the operator's interrupt, link loss, autopilot failover, GPS loss, low battery,
    the offboard watchdog's own HOLD, pilot mode change, camera failure, geofence, refused
    command, a rejected candidate (when ``on_target_lost`` is not ``resume_cruise``), state
    timeout, route end without target. On the ground (PREFLIGHT) the action is ``none``: the
    vehicle is never armed.
    """
    if state in FINAL_STATES:
        return None
    on_ground = state is S.PREFLIGHT

    def act(a: FinalAction) -> FinalAction:
        return "none" if on_ground else a

    if s.interrupt_reason:
        return Abort(s.interrupt_reason, act(s.interrupt_action))
    if s.link_lost_s > s.link_loss_timeout_s and not on_ground:
        return Abort(f"link lost for {s.link_lost_s:.1f} s", act(safety.link_loss_action))
    if s.autopilot_failover and not on_ground:  # it moved on its own: do not carry on
        return Abort(f"autopilot failover during a link loss: {s.autopilot_failover}",
                     act(safety.link_loss_action))
    if not s.gps_ok and not on_ground:
        return Abort("GPS lost", act(safety.gps_loss_action))
    if s.battery_remaining < s.low_battery_fraction:
        return Abort(f"battery low ({s.battery_remaining:.0%})", act(safety.low_battery_action))
    if s.watchdog_hold and not on_ground:  # our own HOLD, not a pilot's: no one flies it
        return Abort(f"offboard watchdog commanded HOLD: {s.watchdog_hold}",
                     act(actions.on_timeout))
    if s.pilot_override:
        return Abort("flight mode changed by the pilot or the autopilot: stop commanding",
                     "release")
    if s.camera_failed:
        return Abort("camera failure: no frames", act(actions.on_camera_failure))
    if not s.goal_inside_geofence:
        return Abort("the approach goal lies outside the geofence", act(actions.on_geofence))
    if s.command_failed:
        return Abort(f"command failed: {s.command_failed}", act(actions.on_timeout))
    if (state is S.TARGET_LOST and s.candidate_rejected
            and actions.on_target_lost != "resume_cruise"):
        return Abort(f"target lost {s.target_losses} times at one place: candidate rejected",
                     act(actions.on_target_lost))
    if state_timed_out(s):
        if state is S.TARGET_LOST:
            if actions.on_target_lost == "resume_cruise":
                return None  # handled by the resume_cruise transition
            return Abort(f"target lost for {s.time_in_state_s:.1f} s",
                         act(actions.on_target_lost))
        return Abort(f"{state.value} timed out after {s.state_timeout_s:g} s",
                     act(actions.on_timeout))
    if state is S.CRUISE and route_finished(s):
        return Abort("route finished without a confirmed target", act(actions.on_route_end))
    return None


class ApproachMachine:
    """The model of the ``transitions`` machine. ``step(snapshot)`` fires at most one
    transition; ``on_change`` is called with (old, new, reason, action) after every state
    change (``action``: the safe action of an abort, else "")."""

    def __init__(self, *, on_change: Callable[[MissionState, MissionState, str, str], None]
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
        old, trigger = self._pending if self._pending else (self.state, "")
        if self._on_change is not None:
            self._on_change(old, self.state, self.reason,
                            self.action if trigger == "abort" else "")

    def _fire(self, trigger: str, *args: Any) -> bool:
        self._pending = (self.state, trigger)
        try:
            return bool(self.trigger(trigger, *args))  # type: ignore[attr-defined]  # added by Machine
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

    @property
    def policy(self) -> StatePolicy:
        return POLICIES[self.state]

    def outcome_action(self, on_done: str) -> str:
        """The action that ends the flight: the failsafe's, else ``actions.on_done``."""
        return self.action if self.state is S.FAILSAFE else on_done


def mermaid_diagram() -> str:
    """The machine as a Mermaid ``stateDiagram-v2`` (transitions' mermaid engine, no graphviz)."""
    from transitions.extensions.diagrams import GraphMachine

    class _Model:
        pass

    model = _Model()
    GraphMachine(model=model, states=MissionState, transitions=TRANSITIONS,
                 initial=S.PREFLIGHT, auto_transitions=False, graph_engine="mermaid",
                 show_conditions=True, title="approach mission")
    text = model.get_graph().draw(None)  # type: ignore[attr-defined]  # added by GraphMachine
    return "\n".join(line.rstrip() for line in text.splitlines()).strip() + "\n"


if __name__ == "__main__":  # regenerate the diagram: python -m eaglemission.missions.approach
    import sys

    sys.stdout.write(mermaid_diagram())
