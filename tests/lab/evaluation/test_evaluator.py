from __future__ import annotations

import math
from dataclasses import dataclass

from eaglemission.lab.evaluation.evaluator import envelope_violations, evaluate
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.guidance import grasp_position

from eaglemission.config import load_config
from eaglemission.geometry import euler_to_quat
from eaglemission.types import VehicleState


@dataclass
class _Result:
    final_state: str = "DONE"
    reason: str = "grasp_complete"
    action: str = "land"
    t_grasp_ready_s: float | None = 10.0


def _traj(points, *, v=(0.0, 0.0, 0.0), yaw=0.0, in_air=True):
    return [VehicleState(t, p, v, euler_to_quat(0, 0, yaw), in_air=in_air, armed=True)
            for t, p in points]


def test_success_and_errors_against_truth() -> None:
    cfg = load_config(check_plugins=False)
    target = (22.0, 1.5, -0.15)
    good = grasp_position(target, 0.0, cfg.tool_point_m, ApproachConfig.of(cfg).grasp.distance_m)
    off = (good[0] + 0.024, good[1] - 0.032, good[2] - 0.01)  # 4 cm horizontal, 1 cm higher
    t0 = 1_000_000_000
    traj = _traj([(t0, (0, 0, 0)), (t0 + 10_000_000_000, off), (t0 + 20_000_000_000, off)])
    traj[-1] = VehicleState(t0 + 20_000_000_000, (0, 0, 0), (0, 0, 0), (1, 0, 0, 0))
    ev = evaluate(_Result(), traj, cfg, target, t0_ns=t0)
    assert math.isclose(ev.horizontal_error_m, 0.04, abs_tol=1e-9)
    assert math.isclose(ev.grasp_distance_m, ApproachConfig.of(cfg).grasp.distance_m + 0.01, abs_tol=1e-9)
    assert ev.success and ev.landed and ev.violations == []
    far = [(t, (p[0] + 0.1, p[1], p[2])) for t, p in ((s.timestamp_ns, s.position_ned_m) for s in traj)]
    assert not evaluate(_Result(), _traj(far), cfg, target, t0_ns=t0).success


def test_failure_must_end_in_the_configured_action() -> None:
    cfg = load_config(check_plugins=False)
    t0 = 0
    landed = [VehicleState(0, (0, 0, 0), (0, 0, 0), (1, 0, 0, 0), in_air=False)]
    r = _Result(final_state="FAILSAFE", reason="link lost", action="return", t_grasp_ready_s=None)
    ev = evaluate(r, landed, cfg, (22, 1.5, -0.15), t0_ns=t0, expected_action="return")
    assert not ev.success and ev.ended_safe and "link lost" in ev.explanation
    ev = evaluate(r, landed, cfg, (22, 1.5, -0.15), t0_ns=t0, expected_action="land")
    assert not ev.ended_safe


def test_envelope_violations_are_episodes() -> None:
    cfg = load_config(check_plugins=False)
    vmax = cfg.safety.max_horizontal_speed_mps
    pts = []
    for i in range(30):
        fast = 10 <= i < 20
        pts.append(VehicleState(i * 100_000_000, (0.0, 0.0, -5.0),
                                (vmax * 1.5 if fast else 1.0, 0.0, 0.0), (1, 0, 0, 0),
                                in_air=True))
    pts.append(VehicleState(31 * 100_000_000, (90.0, 0.0, -25.0), (0, 0, 0), (1, 0, 0, 0),
                            in_air=True))
    v = envelope_violations(pts, cfg, 0)
    kinds = sorted(x.kind for x in v)
    assert kinds == ["geofence", "horizontal_speed", "max_altitude"]
    speed = next(x for x in v if x.kind == "horizontal_speed")
    assert math.isclose(speed.t_s, 1.0) and math.isclose(speed.duration_s, 1.0)


@dataclass
class _Closed(_Result):
    t_gripper_closed_s: float | None = 10.0
    tool_body_at_close_m: tuple[float, float, float] | None = None
    estimated_grasp_error_m: float | None = None


def test_grasped_only_within_2_5_cm_of_the_tool_where_the_arm_held_it() -> None:
    """The judge puts the tool the manipulator read back on the TRUE pose when the gripper
    closed: an arm that reached 2 cm past the vehicle's 4 cm error grasps; 3 cm off does not."""
    cfg = load_config(check_plugins=False)
    target = (22.0, 1.5, -0.15)
    d = ApproachConfig.of(cfg).grasp.distance_m
    good = grasp_position(target, 0.0, cfg.tool_point_m, d)
    off = (good[0] + 0.04, good[1], good[2])  # the vehicle 4 cm north of the grasp pose
    t0 = 1_000_000_000
    traj = _traj([(t0, off), (t0 + 10_000_000_000, off), (t0 + 20_000_000_000, off)])
    home = cfg.tool_point_m
    arm = (home[0] - 0.02, home[1], home[2])  # the arm took 2 cm of the 4 back
    ev = evaluate(_Closed(tool_body_at_close_m=arm, estimated_grasp_error_m=0.0), traj, cfg,
                  target, t0_ns=t0)
    assert ev.gripper_closed and ev.grasped
    assert math.isclose(ev.grasp_error_m, 0.02, abs_tol=1e-9)
    assert math.isclose(ev.vehicle_error_m, 0.04, abs_tol=1e-9)
    assert math.isclose(ev.horizontal_error_m, 0.02, abs_tol=1e-9)  # the arm's tool judged
    short = (home[0] - 0.01, home[1], home[2])
    ev = evaluate(_Closed(tool_body_at_close_m=short, estimated_grasp_error_m=0.0), traj, cfg,
                  target, t0_ns=t0)
    assert not ev.grasped and math.isclose(ev.grasp_error_m, 0.03, abs_tol=1e-9)
    assert "not grasped" in "\n".join(ev.report_lines())
    assert not ev.success and "closed 3.0 cm from the grasp point" in ev.explanation
    # an arm succeeds on the tool it closed at, 3-D: 2 cm low is grasped (the grasp distance's
    # 1 cm tolerance is the fixed tool's: its GRASP_READY pose)
    low = (home[0] - 0.04, home[1], home[2] + 0.02)  # 2 cm under the grasp point
    ev = evaluate(_Closed(tool_body_at_close_m=low, estimated_grasp_error_m=0.0), traj, cfg,
                  target, t0_ns=t0)
    assert ev.grasped and ev.success, ev.explanation
    ev = evaluate(_Closed(t_gripper_closed_s=None), traj, cfg, target, t0_ns=t0)
    assert not ev.gripper_closed and not ev.grasped and ev.grasp_error_m is None
