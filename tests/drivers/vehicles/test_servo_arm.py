"""The servo arm on the autopilot's actuator outputs: joint <-> actuator value <-> pulse
width, and the read-back of SERVO_OUTPUT_RAW (no autopilot needed; the PX4 check is
tests/lab/test_px4_servo_arm.py)."""

from __future__ import annotations

import json

import pytest
from eaglemission.drivers.vehicles.mavsdk.arm import ServoArm, ServoArmConfig
from eaglemission.drivers.vehicles.mavsdk.outputs import ServoOutputLog

HOME = (0.45, 0.0, 0.35)


class _Driver:
    """Stands in for the MAVSDK driver: records set_actuator, holds a read-back log."""

    def __init__(self) -> None:
        self.servo_outputs = ServoOutputLog()
        self.sent: list[tuple[int, float]] = []

    async def set_actuator(self, index: int, value: float) -> None:
        self.sent.append((index, value))


def _pwm(arm: ServoArm, joints: tuple[float, float, float]) -> dict[str, int]:
    c = arm.config
    fields = {f"servo{i}_raw": 1500 for i in range(1, 17)}
    for j, q in zip(c.joints, joints):
        v = j.value_of(q)
        fields[f"servo{j.output}_raw"] = round(c.pwm_min_us + (v + 1) / 2 * (c.pwm_max_us
                                                                              - c.pwm_min_us))
    return fields


def test_joint_value_round_trip_and_clamp() -> None:
    j = ServoArmConfig().joints[2]  # z: -0.08..0.08 m
    assert j.value_of(0.0) == 0.0 and j.value_of(0.08) == 1.0 and j.value_of(0.5) == 1.0
    assert j.offset_of(j.value_of(-0.04)) == pytest.approx(-0.04)


def test_report_reads_the_outputs_back_not_the_command() -> None:
    import asyncio
    import time

    d = _Driver()
    arm = ServoArm(ServoArmConfig(), vehicle=d, tool_point_m=HOME)
    asyncio.run(arm.move_to((0.50, -0.03, 0.39), timeout_s=1.0))
    assert [i for i, _ in d.sent] == [1, 2, 3]
    assert d.sent[0][1] == pytest.approx(0.5) and d.sent[1][1] == pytest.approx(-0.3)
    rep = arm.report()
    assert all(v != v for v in rep.tool_body_m)  # no read-back yet: NaN, not the command
    d.servo_outputs.on_message(time.monotonic_ns(), json.dumps(_pwm(arm, (0.02, 0.0, 0.0))))
    assert arm.report().tool_body_m == pytest.approx((0.47, 0.0, 0.35), abs=1e-3)
    d.servo_outputs.on_message(time.monotonic_ns(), json.dumps(_pwm(arm, (0.05, -0.03, 0.04))))
    assert arm.report().tool_body_m == pytest.approx((0.50, -0.03, 0.39), abs=1e-3)


def test_disarmed_outputs_are_no_read_back_and_the_wait_says_what_to_check() -> None:
    import asyncio
    import time

    from eaglemission.errors import TimeoutError_

    d = _Driver()
    arm = ServoArm(ServoArmConfig(), vehicle=d, tool_point_m=HOME)
    fields = {f"servo{i}_raw": 900 for i in range(1, 17)}  # PX4 disarmed
    d.servo_outputs.on_message(time.monotonic_ns(), json.dumps(fields))
    with pytest.raises(TimeoutError_, match="PWM_MAIN_FUNCn"):
        asyncio.run(arm.wait_joints((0.0, 0.0, 0.0), timeout_s=0.1))


def test_a_goal_within_the_deadband_is_not_sent_again() -> None:
    import asyncio

    d = _Driver()
    arm = ServoArm(ServoArmConfig(deadband_m=0.002), vehicle=d, tool_point_m=HOME)
    asyncio.run(arm.move_to((0.50, 0.0, 0.35), timeout_s=1.0))
    asyncio.run(arm.move_to((0.501, 0.0, 0.35), timeout_s=1.0))
    assert len(d.sent) == 3
    asyncio.run(arm.move_to((0.51, 0.0, 0.35), timeout_s=1.0))
    assert len(d.sent) == 4 and d.sent[-1][0] == 1
