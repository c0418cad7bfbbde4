"""The emulator holds and honours PX4's envelope parameters as PX4 v1.16 does, answers
AUTOPILOT_VERSION as v1.16.0, and the preflight's guard sets, reads back and restores them
through MAVSDK (RTL_RETURN_ALT 30 m / RTL_DESCEND_ALT 10 m in the recorded airframe; the return height by the cone; the RTL climb at MPC_Z_V_AUTO_UP)."""

from __future__ import annotations

import pytest
from eaglemission.drivers.vehicles import px4
from eaglemission.lab.vehicles.autopilot.params import AutopilotParams, rtl_altitude_m
from eaglemission.lab.vehicles.emulator.emulator import Px4Emulator
from emulator_support import flying_pair

from eaglemission.config import SafetyConfig
from eaglemission.safety.autopilot_guard import AutopilotGuard


async def test_defaults_are_px4_v1_16_multicopter_and_the_version_is_reported() -> None:
    emu = Px4Emulator()
    assert (emu.param("RTL_RETURN_ALT"), emu.param("RTL_DESCEND_ALT")) == (30.0, 10.0)
    assert emu.autopilot.params.rtl_return_altitude_m == 30.0
    assert px4.custom_version_bytes() == [0, 0, 0, 0x57, 0x91, 0x53, 0xA3, 0x6E]  # recorded
    assert px4.flight_sw_version() == 0x011000FF
    async with flying_pair(4.0) as (_emu, v, _clock):
        ver = await v.autopilot_version()
    assert ver["flight_sw_version"] == "1.16.0"
    # PX4 sends the hash's first 5 bytes; MAVSDK prints them as hex without leading zeros
    assert ver["flight_sw_git_hash"].startswith(px4.PX4_GIT_HASH[:8]), ver
    assert ver["flight_sw_version_type"] == "RELEASE"


def test_return_height_follows_rtl_return_descend_and_cone_as_recorded() -> None:
    p = AutopilotParams(rtl_return_altitude_m=30.0, rtl_descend_altitude_m=10.0,
                        rtl_cone_half_angle_deg=45.0)
    assert rtl_altitude_m(p, 4.3, 9.9) == pytest.approx(10.0)  # f1: "10 m above destination"
    p2 = AutopilotParams(rtl_return_altitude_m=8.0, rtl_descend_altitude_m=4.0,
                         rtl_cone_half_angle_deg=45.0)
    assert rtl_altitude_m(p2, 4.3, 9.9) == pytest.approx(8.0)  # f2: 8 m
    assert rtl_altitude_m(p, 4.3, 100.0) == pytest.approx(30.0)  # far away: RTL_RETURN_ALT


def test_the_rtl_climb_is_limited_by_mpc_z_v_auto_up() -> None:
    emu = Px4Emulator()
    emu.set_param("MPC_Z_V_AUTO_UP", 0.8)
    assert emu.autopilot.params.auto_vertical_speeds()["max_up_speed_mps"] == 0.8


async def test_guard_sets_inside_the_envelope_reads_back_and_restores() -> None:
    safety = SafetyConfig(max_altitude_m=15.0, max_vertical_speed_mps=1.0)
    async with flying_pair(4.0) as (emu, v, _clock):
        guard = AutopilotGuard(v, safety, cruise_altitude_m=5.0)
        rep = await guard.apply()
        assert rep.version["flight_sw_version"] == "1.16.0"
        assert rep.values["RTL_RETURN_ALT"] == 30.0 and rep.values["MPC_Z_V_AUTO_UP"] == 3.0
        assert not rep.missing and not rep.refused
        got = {c.name: (c.old, c.new) for c in rep.set_ok}
        assert got["RTL_RETURN_ALT"] == (30.0, 5.0) and got["RTL_DESCEND_ALT"] == (10.0, 5.0)
        assert got["MPC_Z_V_AUTO_UP"] == (3.0, 0.9)
        # the emulator holds and flies the new values
        assert emu.param("RTL_RETURN_ALT") == 5.0
        assert emu.autopilot.params.rtl_return_altitude_m == 5.0
        assert emu.autopilot.params.auto_up_speed_mps == pytest.approx(0.9)
        assert await v.get_param("RTL_RETURN_ALT") == 5.0
        done = await guard.restore()
        assert all(r["restored"] for r in done) and len(done) == len(rep.set_ok)
        assert await v.get_param("RTL_RETURN_ALT") == 30.0  # read back after restoring
        assert emu.param("MPC_Z_V_AUTO_UP") == 3.0
        assert await guard.restore() == []  # once


async def test_guard_refuses_naming_the_parameter_and_the_envelope_key() -> None:
    safety = SafetyConfig(max_altitude_m=15.0, autopilot_params="refuse")
    async with flying_pair(4.0) as (emu, v, _clock):
        rep = await AutopilotGuard(v, safety, cruise_altitude_m=5.0).apply()
        assert "RTL_RETURN_ALT=30 m" in rep.refused and "safety.max_altitude_m" in rep.refused
        assert "MPC_Z_V_AUTO_UP=3 m/s" in rep.refused
        assert "safety.max_vertical_speed_mps" in rep.refused
        assert not rep.set_ok and emu.param("RTL_RETURN_ALT") == 30.0


async def test_guard_keeps_the_horizontal_speed_limit_inside_the_envelope() -> None:
    """MPC_XY_VEL_MAX (every horizontal move, offboard included) above the envelope is set
    inside it through PARAM_SET, flown by the emulator, and restored: never only a warning."""
    safety = SafetyConfig(max_horizontal_speed_mps=4.0)
    emulator = {"params": {"MPC_XY_VEL_MAX": 12.0}}
    async with flying_pair(4.0, emulator=emulator) as (emu, v, _clock):
        guard = AutopilotGuard(v, safety, cruise_altitude_m=5.0)
        rep = await guard.apply()
        got = {c.name: (c.old, c.new, c.envelope_key) for c in rep.set_ok}
        assert got["MPC_XY_VEL_MAX"] == (12.0, 3.6, "safety.max_horizontal_speed_mps"), got
        assert not rep.refused
        assert emu.param("MPC_XY_VEL_MAX") == pytest.approx(3.6)
        assert await v.get_param("MPC_XY_VEL_MAX") == pytest.approx(3.6)
        await guard.restore()
        assert await v.get_param("MPC_XY_VEL_MAX") == 12.0
        assert emu.param("MPC_XY_VEL_MAX") == 12.0
