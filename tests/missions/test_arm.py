"""The mission's side of an arm: the grasp point in body FRD, readiness inside the workspace,
tracking, and the gripper waiting for the measured error."""

from __future__ import annotations

import asyncio
import math

import pytest
from eaglemission.lab.manipulators.simulated_arm import SimulatedArm, SimulatedArmConfig
from eaglemission.missions.arm import ArmTracking, grasp_point_body
from eaglemission.missions.log import MissionLog

from eaglemission.clock import ManualClock
from eaglemission.geometry import euler_to_quat
from eaglemission.types import VehicleState

HOME = (0.45, 0.0, 0.35)
TARGET = (10.0, 2.0, -0.15)  # top-face centre, NED


def _vs(n: float, e: float, d: float, yaw_deg: float = 0.0) -> VehicleState:
    return VehicleState(0, (n, e, d), (0.0, 0.0, 0.0), euler_to_quat(0, 0, yaw_deg),
                        in_air=True, armed=True)


def test_the_grasp_point_in_body_frd_follows_position_and_yaw() -> None:
    # the vehicle right where the home tool point is 0.175 m above the target
    at = _vs(TARGET[0] - 0.45, TARGET[1], TARGET[2] - 0.175 - 0.35)
    assert grasp_point_body(at.position_ned_m, at.attitude_q, TARGET, 0.175) == \
        pytest.approx(HOME)
    turned = _vs(TARGET[0], TARGET[1] - 0.45, TARGET[2] - 0.525, yaw_deg=90.0)
    assert grasp_point_body(turned.position_ned_m, turned.attitude_q, TARGET, 0.175) == \
        pytest.approx(HOME)


def _tracking(clock: ManualClock, vs: VehicleState, **params: object) -> ArmTracking:
    arm = SimulatedArm(SimulatedArmConfig.model_validate(params), clock=clock,
                       tool_point_m=HOME)
    return ArmTracking(arm, MissionLog(None, now_ns=clock.now_ns), grasp_distance_m=0.175,
                       command_s=1.0, period_s=0.05, state=lambda: (vs, TARGET))


def test_ready_only_inside_the_workspace_shrunk_by_its_margin() -> None:
    clock = ManualClock()
    base = (TARGET[0] - 0.45, TARGET[1], TARGET[2] - 0.525)
    inside = _vs(base[0] - 0.07, base[1] + 0.05, base[2])  # the grasp point 7 cm ahead
    beyond = _vs(base[0] - 0.09, base[1], base[2])  # 9 cm: within 10, not within 10 - 2
    t = _tracking(clock, inside)
    assert t.reachable(inside, TARGET)
    assert not t.reachable(beyond, TARGET)


def test_tracking_brings_the_measured_error_to_zero() -> None:
    clock = ManualClock()
    base = (TARGET[0] - 0.45, TARGET[1], TARGET[2] - 0.525)
    vs = _vs(base[0] + 0.05, base[1] - 0.04, base[2] + 0.02)
    t = _tracking(clock, vs, latency_s=0.04, joint_speed_mps=0.5)
    before = t.error_m(vs, TARGET)
    assert before == pytest.approx(math.sqrt(0.05**2 + 0.04**2 + 0.02**2))

    async def fly() -> None:
        t.tracking = True
        task = asyncio.create_task(t.run())
        for _ in range(20):
            t.wake.set()
            await asyncio.sleep(0)
            clock.advance(0.02)
            await asyncio.sleep(0)
        t.stopping = True
        t.wake.set()
        await asyncio.wait_for(task, timeout=5.0)

    asyncio.run(fly())
    assert t.commands > 0
    assert t.error_m(vs, TARGET) == pytest.approx(0.0, abs=1e-9)


def test_settled_only_once_the_tool_reaches_the_point_last_commanded() -> None:
    """Within the latency the tool has not moved yet (its error unchanged): not settled."""
    clock = ManualClock()
    base = (TARGET[0] - 0.45, TARGET[1], TARGET[2] - 0.525)
    vs = _vs(base[0] + 0.01, base[1] - 0.005, base[2])
    t = _tracking(clock, vs, latency_s=0.04, joint_speed_mps=0.5)
    assert not t.settled()  # nothing commanded yet
    seen: list[tuple[float, bool]] = []

    async def fly() -> None:
        t.follow(True)
        task = asyncio.create_task(t.run())
        for _ in range(10):
            await asyncio.sleep(0)
            seen.append((t.error_m(vs, TARGET) or 0.0, t.settled()))
            clock.advance(0.02)
            t.wake.set()
            await asyncio.sleep(0)
        t.stopping = True
        t.wake.set()
        await asyncio.wait_for(task, timeout=5.0)

    asyncio.run(fly())
    first_error = seen[0][0]
    assert first_error == pytest.approx(math.hypot(0.01, 0.005))
    # during the latency the error stands still and the arm is not settled
    assert seen[1][0] == pytest.approx(first_error) and not seen[1][1]
    assert seen[-1][1] and seen[-1][0] == pytest.approx(0.0, abs=1e-9)


def test_no_command_while_tracking_is_off() -> None:
    clock = ManualClock()
    vs = _vs(TARGET[0] - 0.40, TARGET[1], TARGET[2] - 0.525)
    t = _tracking(clock, vs)

    async def idle() -> None:
        task = asyncio.create_task(t.run())
        for _ in range(5):
            t.wake.set()
            await asyncio.sleep(0)
        t.stopping = True
        t.wake.set()
        await asyncio.wait_for(task, timeout=5.0)

    asyncio.run(idle())
    assert t.commands == 0 and t.arm.report().tool_body_m == pytest.approx(HOME)


def test_a_view_the_tool_covers_is_the_arms_not_the_targets() -> None:
    """The shape check skips views whose detection the tool overlaps: from the grasp pose the
    wide camera sees the gripper in front of the target's far edge."""
    from eaglemission.config import load_config

    clock = ManualClock()
    at = _vs(TARGET[0] - 0.45, TARGET[1], TARGET[2] - 0.525)
    t = _tracking(clock, at)
    model = load_config().cameras.wide.to_model("wide")
    from eaglemission.missions.views import project_target

    tool_px = project_target(model, at, (TARGET[0], TARGET[1], TARGET[2] - 0.175))
    u, v = float(tool_px[0]), float(tool_px[1])
    around = [(u - 40, v - 10), (u + 40, v - 10), (u + 40, v + 200), (u - 40, v + 200)]
    assert t.hides(model, around)
    aside = [(u + 300, v), (u + 400, v), (u + 400, v + 100), (u + 300, v + 100)]
    assert not t.hides(model, aside)


def test_the_tool_covers_what_lies_behind_it_in_the_cameras_view() -> None:
    from eaglemission.missions.views import project_target

    from eaglemission.config import load_config

    clock = ManualClock()
    at = _vs(TARGET[0] - 2.5, TARGET[1], TARGET[2] - 1.5)
    t = _tracking(clock, at)
    model = load_config().cameras.wide.to_model("wide")
    tool_ned = (at.position_ned_m[0] + HOME[0], at.position_ned_m[1] + HOME[1],
                at.position_ned_m[2] + HOME[2])
    u, v = project_target(model, at, tool_ned)
    assert t.covers(model, (u, v)) and t.covers(model, (u + 10, v + 10))
    assert not t.covers(model, (u + 200, v))
    assert not t.covers(model, (float("nan"), v))
