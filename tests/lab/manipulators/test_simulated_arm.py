"""The simulated arm: latency, joint speed, the workspace, its gripper, and that the synthetic
cameras draw it."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from eaglemission.lab.manipulators.simulated_arm import SimulatedArm, SimulatedArmConfig

from eaglemission.clock import ManualClock
from eaglemission.errors import TimeoutError_
from eaglemission.flight.context import MANIPULATOR, SharedContext

HOME = (0.45, 0.0, 0.35)


def _arm(**params: object) -> tuple[SimulatedArm, ManualClock]:
    clock = ManualClock()
    arm = SimulatedArm(SimulatedArmConfig.model_validate(params), clock=clock, tool_point_m=HOME)
    asyncio.run(arm.start(timeout_s=1.0))
    return arm, clock


def test_a_command_waits_for_the_latency_then_moves_at_the_joint_speed() -> None:
    arm, clock = _arm(latency_s=0.1, joint_speed_mps=0.2)
    asyncio.run(arm.move_to((0.50, 0.03, 0.35), timeout_s=1.0))
    clock.advance(0.1)
    assert arm.report().tool_body_m == pytest.approx(HOME)
    clock.advance(0.1)  # 0.02 m along each moving axis
    assert arm.report().tool_body_m == pytest.approx((0.47, 0.02, 0.35))
    clock.advance(1.0)
    assert arm.report().tool_body_m == pytest.approx((0.50, 0.03, 0.35))
    assert arm.report().joints == pytest.approx((0.05, 0.03, 0.0))


def test_a_target_outside_the_workspace_is_clamped_to_it() -> None:
    arm, clock = _arm(latency_s=0.0)
    asyncio.run(arm.move_to((1.0, -1.0, 0.0), timeout_s=1.0))
    clock.advance(2.0)
    assert arm.report().tool_body_m == pytest.approx((0.55, -0.10, 0.27))


def test_the_integration_does_not_depend_on_when_it_is_read() -> None:
    a, ca = _arm(latency_s=0.05, joint_speed_mps=0.3)
    b, cb = _arm(latency_s=0.05, joint_speed_mps=0.3)
    for arm, clock, reads in ((a, ca, 1), (b, cb, 40)):
        asyncio.run(arm.move_to((0.52, 0.05, 0.30), timeout_s=1.0))
        for _ in range(reads):
            clock.advance(0.2 / reads)
            arm.report()
        asyncio.run(arm.move_to((0.40, -0.05, 0.40), timeout_s=1.0))
        clock.advance(0.15)
    assert a.report().tool_body_m == pytest.approx(b.report().tool_body_m, abs=1e-12)


def test_the_gripper_closes_in_its_time_and_a_short_timeout_says_so() -> None:
    arm, clock = _arm(gripper_close_s=0.3)
    t0 = clock.now_ns()
    asyncio.run(arm.close_gripper(timeout_s=1.0))
    assert arm.report().gripper_closed and clock.now_ns() - t0 == 300_000_000
    slow, _ = _arm(gripper_close_s=2.0)
    with pytest.raises(TimeoutError_, match="gripper_close_s"):
        asyncio.run(slow.close_gripper(timeout_s=0.5))
    assert not slow.report().gripper_closed


def test_the_history_answers_for_a_camera_that_renders_earlier() -> None:
    arm, clock = _arm(latency_s=0.0, joint_speed_mps=0.1)
    t0 = clock.now_ns()
    asyncio.run(arm.move_to((0.55, 0.0, 0.35), timeout_s=1.0))
    clock.advance(0.5)
    arm.report()
    assert arm.tool_body_at(t0)[0] == pytest.approx(0.45)
    assert arm.tool_body_at(clock.now_ns())[0] == pytest.approx(0.50)


def test_the_arm_registers_for_the_cameras_only_when_drawn() -> None:
    shared = SharedContext()
    arm = SimulatedArm(SimulatedArmConfig(), clock=ManualClock(), tool_point_m=HOME,
                       shared=shared)
    assert shared.get(MANIPULATOR) is arm
    hidden = SharedContext()
    SimulatedArm(SimulatedArmConfig(drawn=False), clock=ManualClock(), tool_point_m=HOME,
                 shared=hidden)
    assert hidden.get(MANIPULATOR) is None


def test_the_wide_camera_sees_the_arm_under_the_body() -> None:
    from eaglemission.lab.world.render import SyntheticWorld
    from eaglemission.lab.world.synthetic import SyntheticWorldConfig

    from eaglemission.config import load_config
    from eaglemission.geometry import euler_to_quat

    cfg = load_config()
    model = cfg.cameras.wide.to_model("wide")
    world = SyntheticWorld(SyntheticWorldConfig(seed=3, target_north_m=30.0, noise_sigma=0.0),
                           cfg.target)
    q = euler_to_quat(0.0, 0.0, 0.0)
    pose = ((0.0, 0.0, -5.0), q)
    plain, _ = world.render(model, *pose, 1_000_000_000)
    drawn, _ = world.render(model, *pose, 1_000_000_000, tool_body_m=HOME)
    moved, _ = world.render(model, *pose, 1_000_000_000, tool_body_m=(0.55, 0.1, 0.35))
    changed = np.any(plain != drawn, axis=2)
    assert changed.sum() > 500  # the slide and the block cover some of the image
    rows, cols = np.nonzero(changed)
    assert rows.min() > model.height_px / 2  # under the body: in the lower half
    assert np.any(drawn != moved)  # drawn where the tool is
