"""The ``actuator_servos`` arm against a real PX4 v1.16 SITL: every commanded joint is seen in
the autopilot's own output telemetry (SERVO_OUTPUT_RAW), and how long that takes at the rate
PX4 sends it. Runs with ``EAGLEMISSION_PX4_BUILD`` (a fresh PX4 for the test) or
``EAGLEMISSION_PX4_URL``; skipped otherwise (the ``px4_sitl`` fixture, tests/conftest.py).

PX4 is set up as a field team would: the arm's outputs 5-7 get the functions "Peripheral via
Actuator Set 1-3" (``PWM_MAIN_FUNC5..7 = 301..303``), and ``COM_PREARM_MODE = 2`` so the
outputs move on the ground, disarmed. Run with ``-s`` for the figures.
"""

from __future__ import annotations

import asyncio
import statistics
import time
from typing import Any

import pytest
from eaglemission.drivers.vehicles.mavsdk.arm import ServoArm, ServoArmConfig
from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle

pytestmark = [pytest.mark.px4, pytest.mark.machine]

HOME = (0.45, 0.0, 0.35)
TARGETS = [(0.05, 0.0, 0.0), (0.05, -0.07, 0.0), (0.05, -0.07, 0.06), (-0.09, 0.03, -0.04),
           (0.0, 0.0, 0.0), (0.10, 0.10, 0.08), (-0.10, -0.10, -0.08), (0.02, 0.04, -0.02)]
"""Joint offsets (m from home), every joint moving in most steps, the travel's ends included."""


async def _check(url: str) -> dict[str, Any]:
    v = MavsdkVehicle(MavsdkVehicle.Config(url=url, connect_timeout_s=30))
    await v.connect()
    try:
        version = await v.autopilot_version()
        for out, fn in ((5, 301), (6, 302), (7, 303)):
            await v.set_param_int(f"PWM_MAIN_FUNC{out}", fn)
        await v.set_param_int("COM_PREARM_MODE", 2)
        arm = ServoArm(ServoArmConfig(deadband_m=0.0), vehicle=v, tool_point_m=HOME)
        await arm.start(timeout_s=5.0)
        await arm.wait_joints((0.0, 0.0, 0.0), timeout_s=10.0)
        delays, ack_s = [], []
        for joints in TARGETS:
            t0 = time.monotonic()
            await arm.move_to((HOME[0] + joints[0], HOME[1] + joints[1], HOME[2] + joints[2]),
                              timeout_s=5.0)
            ack_s.append(time.monotonic() - t0)
            delays.append(ack_s[-1] + await arm.wait_joints(joints, timeout_s=3.0))
            seen = arm.report()
            assert seen.joints == pytest.approx(joints, abs=arm.config.readback_tolerance_m)
        t_rate = time.monotonic_ns()
        await asyncio.sleep(3.0)
        msgs = [o for o in v.servo_outputs.since(t_rate) if o.port == 0]
        return {"version": version, "delays_s": delays, "ack_s": ack_s,
                "servo_output_raw_hz": len(msgs) / 3.0,
                "pwm_last": msgs[-1].pwm_us[:8] if msgs else None}
    finally:
        await v.close()


def test_each_commanded_joint_is_seen_in_the_autopilot_outputs(px4_sitl: Any) -> None:
    res = asyncio.run(_check(px4_sitl.url))
    d = res["delays_s"]
    print(f"\nPX4 {res['version']}: {len(d)} joint commands (3 joints each), each read back "
          f"from SERVO_OUTPUT_RAW at {res['servo_output_raw_hz']:.1f} Hz; command to "
          f"read-back median {statistics.median(d) * 1e3:.0f} ms, max {max(d) * 1e3:.0f} ms "
          f"(the three acknowledged DO_SET_ACTUATOR: median "
          f"{statistics.median(res['ack_s']) * 1e3:.0f} ms); last outputs 1-8 "
          f"{res['pwm_last']} us")
    assert res["servo_output_raw_hz"] > 5.0
    # read back within the next few messages at PX4's rate (10 Hz)
    assert max(d) < 1.0
