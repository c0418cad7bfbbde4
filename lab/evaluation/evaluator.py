"""The evaluator: the ONLY consumer of ground truth (the simulator's true trajectory and the
synthetic world's target). Separate from the mission, which never sees truth.

It computes, for one flight: success (GRASP_READY reached with the TRUE tool point within the
configured grasp tolerance of the true grasp pose), the final tool-point error (horizontal, and
the grasp distance = height of the tool point above the target's true top face), the time to
GRASP_READY, the true tool-to-target error when the gripper closed (the tool where the
manipulator read it back, on the true vehicle pose; "grasped" only within
:data:`GRASPED_WITHIN_M`) with the vehicle's own error then, and envelope violations over the whole flight (takeoff, route, approach, return):
altitude band, horizontal and vertical speed, geofence.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.guidance import tool_errors, tool_point_ned
from eaglemission.missions.result import MissionResult

from eaglemission.config import MissionFile
from eaglemission.geometry.geofence import inside_geofence
from eaglemission.types import VehicleState

GRASPED_WITHIN_M = 0.025
"""A closed gripper grasped the target when the true tool point was within this distance (3-D)
of the grasp point (``grasp.distance_m`` above the target's top-face centre)."""


@dataclass(frozen=True)
class Tolerances:
    """Slack on the envelope when judging the TRUE trajectory (the envelope constrains
    setpoints; the airframe overshoots a little, and wind adds to ground speed)."""

    speed_fraction: float = 0.15
    speed_mps: float = 0.3
    altitude_m: float = 0.5
    geofence_m: float = 0.5
    grasp_horizontal_m: float = 0.05  # the grasp's requirement: final tool-point error <= 0.05 m horizontally


@dataclass(frozen=True)
class Violation:
    kind: str
    t_s: float
    value: float
    limit: float
    duration_s: float


@dataclass
class Evaluation:
    success: bool
    reached_grasp_ready: bool
    final_state: str
    reason: str
    action: str
    time_to_grasp_ready_s: float | None
    horizontal_error_m: float | None
    grasp_distance_m: float | None
    violations: list[Violation] = field(default_factory=list)
    ended_safe: bool = True
    landed: bool = False
    explanation: str = ""
    judged_on: str = "truth"
    """``"truth"`` (the simulator's) or ``"estimate"`` (the autopilot's own reported states)."""
    trajectory: list[VehicleState] = field(default_factory=list, repr=False)
    """The states judged (true ones when ``judged_on == "truth"``)."""
    target_position_ned_m: tuple[float, float, float] | None = None
    """The target's true top-face centre, when a world knows it."""
    gripper_closed: bool = False
    grasp_error_m: float | None = None
    """True distance (3-D) from the tool point to the grasp point when the gripper closed."""
    grasp_error_horizontal_m: float | None = None
    vehicle_error_m: float | None = None
    """The vehicle's own error then: the home tool point (``tool_point_m``) from the grasp
    point, 3-D (what a fixed tool would have missed by)."""
    grasped: bool = False
    """The gripper closed with ``grasp_error_m`` within :data:`GRASPED_WITHIN_M` (on truth)."""

    def as_dict(self) -> dict[str, Any]:
        from eaglemission.missions.log import to_jsonable

        out: dict[str, Any] = to_jsonable({k: v for k, v in vars(self).items()
                                           if k not in ("trajectory", "target_position_ned_m")})
        return out

    def report_lines(self) -> list[str]:
        truth = self.judged_on == "truth"
        basis = "true" if truth else "judged on the autopilot's estimate (no ground truth):"
        out = []
        if self.horizontal_error_m is not None and self.grasp_distance_m is not None:
            out.append(f"{basis} tool-point error: horizontal {self.horizontal_error_m * 100:.1f} "
                       f"cm, grasp distance {self.grasp_distance_m:.3f} m")
        if self.gripper_closed and self.grasp_error_m is not None:
            veh = "" if self.vehicle_error_m is None else \
                f"; the vehicle's own error {self.vehicle_error_m * 100:.1f} cm"
            out.append(f"{basis} tool-to-target error when the gripper closed: "
                       f"{self.grasp_error_m * 100:.1f} cm (horizontal "
                       f"{(self.grasp_error_horizontal_m or 0.0) * 100:.1f} cm){veh}: "
                       + ("grasped" if self.grasped else
                          f"not grasped (> {GRASPED_WITHIN_M * 100:.1f} cm)"))
        elif not self.gripper_closed:
            out.append("gripper: not closed")
        out.append(f"envelope violations ({'true' if truth else 'reported'} trajectory): "
                   f"{len(self.violations)}" + "".join(
                       f"\n  {v.kind} at {v.t_s:.1f} s: {v.value:.2f} > {v.limit:.2f} for "
                       f"{v.duration_s:.1f} s" for v in self.violations))
        verdict = "SUCCESS" if self.success else "FAILURE"
        if not truth:
            verdict += " (not judged on ground truth)"
        out.append(f"evaluator: {verdict}" + (f" -- {self.explanation}" if self.explanation
                                             else ""))
        return out


def _state_at(traj: Sequence[VehicleState], t_ns: int) -> VehicleState:
    times = [s.timestamp_ns for s in traj]
    i = int(np.searchsorted(times, t_ns))
    return traj[min(max(i, 0), len(traj) - 1)]


def envelope_violations(traj: Sequence[VehicleState], cfg: MissionFile, t0_ns: int,
                        tol: Tolerances = Tolerances()) -> list[Violation]:
    """Contiguous episodes where the TRUE state left the safety envelope (in the air only)."""
    s = cfg.safety
    checks: dict[str, tuple[Callable[[VehicleState], float], float, int]] = {
        "max_altitude": (lambda st: -st.position_ned_m[2], s.max_altitude_m + tol.altitude_m, 1),
        "horizontal_speed": (lambda st: math.hypot(*st.velocity_ned_mps[:2]),
                             s.max_horizontal_speed_mps * (1 + tol.speed_fraction) + tol.speed_mps, 1),
        "vertical_speed": (lambda st: abs(st.velocity_ned_mps[2]),
                           s.max_vertical_speed_mps * (1 + tol.speed_fraction) + tol.speed_mps, 1),
    }
    if s.min_altitude_m > 0:
        checks["min_altitude"] = (lambda st: -st.position_ned_m[2],
                                  s.min_altitude_m - tol.altitude_m, -1)
    out: list[Violation] = []
    open_: dict[str, list[float]] = {}
    last_t = t0_ns
    for st in traj:
        t = st.timestamp_ns
        last_t = t
        airborne = bool(getattr(st, "in_air", True))
        for kind, (fn, limit, sign) in checks.items():
            v = float(fn(st))
            bad = airborne and (v - limit) * sign > 0
            if kind == "min_altitude":
                bad = bad and getattr(st, "armed", True)
            _track(out, open_, kind, bad, t, t0_ns, v, limit, sign)
        n, e = st.position_ned_m[0], st.position_ned_m[1]
        outside = not inside_geofence(s.geofence, n, e)
        if outside and tol.geofence_m > 0:
            # tolerate a small excursion: test points pulled towards home by the tolerance
            r = math.hypot(n, e)
            if r > 0:
                k = max(0.0, r - tol.geofence_m) / r
                outside = not inside_geofence(s.geofence, n * k, e * k)
        _track(out, open_, "geofence", outside, t, t0_ns, math.hypot(n, e),
               s.geofence.radius_m or math.nan, 1)
    for kind in list(open_):
        _close(out, open_, kind, last_t, t0_ns)
    return out


def _track(out: list[Violation], open_: dict[str, list[float]], kind: str, bad: bool, t: int,
           t0: int, v: float, limit: float, sign: int) -> None:
    if bad:
        ep = open_.setdefault(kind, [t, v, limit])
        if (v - ep[1]) * sign > 0:
            ep[1] = v
    elif kind in open_:
        _close(out, open_, kind, t, t0)


def _close(out: list[Violation], open_: dict[str, list[float]], kind: str, t: int, t0: int) -> None:
    start, worst, limit = open_.pop(kind)
    out.append(Violation(kind, (start - t0) * 1e-9, worst, limit, (t - start) * 1e-9))


def evaluate(result: MissionResult, trajectory: Sequence[VehicleState], cfg: MissionFile,
             target_position_ned_m: Sequence[float] | None, *, t0_ns: int,
             expected_action: str | None = None,
             tolerances: Tolerances = Tolerances(), judged_on: str = "truth") -> Evaluation:
    """Judge one flight against the truth.

    Parameters
    ----------
    result : the mission's :class:`~eaglemission.missions.runner.MissionResult`
    trajectory : TRUE vehicle states (``timestamp_ns``, ``position_ned_m``,
        ``velocity_ned_mps``, ``attitude_q``, ``in_air``), time-ordered
    target_position_ned_m : TRUE centre of the target's top face; None when no world knows it
        (then the tool-point errors are the mission's own estimate at GRASP_READY)
    t0_ns : the mission start on the same clock (``result`` times are relative to it)
    expected_action : the safe action the configuration prescribes for this run's failure
        (``ended_safe`` checks the mission chose it), None to skip that check
    judged_on : ``"truth"``, or ``"estimate"`` when ``trajectory`` is the autopilot's report
    """
    traj = list(trajectory)
    grasp = ApproachConfig.of(cfg).grasp
    h_err = dist = None
    t_gr = result.t_grasp_ready_s
    t_close, body_close = _closed(result)
    arm_closed = (getattr(result, "estimated_grasp_error_m", None) is not None
                  and t_close is not None and body_close is not None)
    if t_gr is not None and traj and target_position_ned_m is not None:
        # a fixed tool: its point at GRASP_READY; an arm: where it held the tool at the close
        t_tool = t_close if arm_closed and t_close is not None else t_gr
        st = _state_at(traj, t0_ns + int(t_tool * 1e9))
        body = body_close if arm_closed and body_close is not None else cfg.tool_point_m
        tool = tool_point_ned(st.position_ned_m, st.attitude_q, body)
        h_err, dist = tool_errors(tool, target_position_ned_m)
    elif t_gr is not None and result.estimated_tool_errors_m is not None:
        # no known target (a real flight, a replay): the mission's own estimate is all there is
        h_err, dist = result.estimated_tool_errors_m
    closed = grasp_at_close(result, traj, cfg, target_position_ned_m, t0_ns=t0_ns)
    if arm_closed and "grasped" in closed:
        within = bool(closed["grasped"])  # an arm: the tool it closed at, 3-D within 2.5 cm
    else:
        within = (h_err is not None and dist is not None
                  and h_err <= tolerances.grasp_horizontal_m
                  and abs(dist - grasp.distance_m) <= grasp.tolerance_m)
    violations = envelope_violations(traj, cfg, t0_ns, tolerances) if traj else []
    landed = bool(traj) and not getattr(traj[-1], "in_air", False)
    ended_safe = True
    explanation = ""
    if result.final_state == "FAILSAFE":
        explanation = f"failsafe: {result.reason} -> {result.action}"
        if expected_action is not None and result.action != expected_action:
            ended_safe = False
            explanation += f" (configured: {expected_action})"
        if result.action in ("land", "return") and not landed:
            ended_safe = False
            explanation += " (still in the air at the end)"
    elif t_gr is None:
        ended_safe = False
        explanation = f"ended in {result.final_state} without GRASP_READY: {result.reason}"
    elif not within and arm_closed and "grasp_error_m" in closed:
        explanation = (f"the gripper closed {closed['grasp_error_m'] * 100:.1f} cm from the "
                       f"grasp point (true; grasped within {GRASPED_WITHIN_M * 100:g} cm)")
    elif not within:
        explanation = (f"GRASP_READY with true tool-point error {h_err:.3f} m horizontal, "
                       f"grasp distance {dist:.3f} m")
    return Evaluation(
        judged_on=judged_on, trajectory=traj,
        target_position_ned_m=None if target_position_ned_m is None else (
            float(target_position_ned_m[0]), float(target_position_ned_m[1]),
            float(target_position_ned_m[2])),
        success=bool(within) and result.final_state == "DONE",
        reached_grasp_ready=t_gr is not None, final_state=result.final_state,
        reason=result.reason, action=result.action, time_to_grasp_ready_s=t_gr,
        horizontal_error_m=h_err, grasp_distance_m=dist, violations=violations,
        ended_safe=ended_safe, landed=landed, explanation=explanation,
        gripper_closed=t_close is not None, **closed)


def _closed(result: MissionResult) -> tuple[float | None, tuple[float, float, float] | None]:
    """When the gripper closed and the tool's body point then (None: it did not close)."""
    return (getattr(result, "t_gripper_closed_s", None),
            getattr(result, "tool_body_at_close_m", None))


def grasp_at_close(result: MissionResult, traj: Sequence[VehicleState], cfg: MissionFile,
                   target_position_ned_m: Sequence[float] | None, *, t0_ns: int
                   ) -> dict[str, Any]:
    """The true tool-to-target error when the gripper closed: the tool point the manipulator
    read back (body FRD) on the TRUE vehicle pose then, against the true grasp point; and the
    vehicle's own error (the home tool point). Empty when the gripper did not close or nothing
    knows the target."""
    t_c, tool_body = _closed(result)
    if t_c is None or tool_body is None or not traj or target_position_ned_m is None:
        return {}
    st = _state_at(traj, t0_ns + int(t_c * 1e9))
    grasp_distance = ApproachConfig.of(cfg).grasp.distance_m
    goal = np.array([target_position_ned_m[0], target_position_ned_m[1],
                     target_position_ned_m[2] - grasp_distance])
    tool = np.asarray(tool_point_ned(st.position_ned_m, st.attitude_q, tool_body))
    home = np.asarray(tool_point_ned(st.position_ned_m, st.attitude_q, cfg.tool_point_m))
    err = float(np.linalg.norm(tool - goal))
    return {"grasp_error_m": err,
            "grasp_error_horizontal_m": float(np.hypot(*(tool - goal)[:2])),
            "vehicle_error_m": float(np.linalg.norm(home - goal)),
            "grasped": err <= GRASPED_WITHIN_M}
