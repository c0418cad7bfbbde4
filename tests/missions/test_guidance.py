from __future__ import annotations

import math

import numpy as np
from eaglemission.missions import guidance as gd

from eaglemission.geometry import euler_to_quat


def test_grasp_position_puts_the_tool_point_above_the_target() -> None:
    target = (22.0, 1.5, -0.15)
    tool = (0.45, 0.0, 0.35)
    for yaw in (0.0, 37.0, -120.0):
        p = gd.grasp_position(target, yaw, tool, 0.175)
        tp = gd.tool_point_ned(p, euler_to_quat(0, 0, yaw), tool)
        h, d = gd.tool_errors(tp, target)
        assert h < 1e-9 and math.isclose(d, 0.175, abs_tol=1e-9)


def test_standoff_is_short_of_the_target_along_the_approach() -> None:
    p = gd.standoff_position((10.0, 0.0, -0.2), 90.0, 2.5, 1.5)
    assert np.allclose(p, (10.0, -2.5, -1.7))


def test_route_and_carrot() -> None:
    route = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)]
    assert gd.route_length_m(route) == 20.0
    n, e, yaw = gd.route_point(route, 15.0)
    assert (n, e) == (10.0, 5.0) and yaw == 90.0
    assert gd.along_route_m(route, 10.5, 4.0) == 14.0
    c = gd.step_towards((0, 0, 0), (10, 0, 0), 0.5)
    assert c == (0.5, 0.0, 0.0)
    assert gd.step_towards((0, 0, 0), (0.1, 0, 0), 0.5) == (0.1, 0.0, 0.0)
    assert gd.yaw_step_deg(170.0, -170.0, 5.0) == 175.0  # through +-180, not the long way
