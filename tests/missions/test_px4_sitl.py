"""The mission on a real PX4 SITL (SIH), synthetic cameras rendering from PX4's telemetry.

Skipped unless ``EAGLEMISSION_PX4_URL`` is set (e.g. ``udpin://0.0.0.0:14540``). It cannot run
on the development machines (no PX4 there): it is written from PX4's documented behaviour
(v1.16): offboard needs a setpoint stream before the switch (MAVSDK sends the first one),
COM_OF_LOSS_T / COM_OBL_RC_ACT decide what happens when setpoints stop, NAV_DLL_ACT on data-link
loss, COM_LOW_BAT_ACT on low battery, GF_ACTION at the fence; takeoff to 5 m takes ~9 s and the
heartbeat (mode, armed) arrives at 1 Hz, so every wait is generous.
"""

from __future__ import annotations

import os

import pytest

from eaglemission.config import load_config
from eaglemission.names import ENV_PX4_URL

pytestmark = [pytest.mark.px4, pytest.mark.skipif(
    not os.environ.get(ENV_PX4_URL), reason=f"no PX4 SITL: set {ENV_PX4_URL}")]


def test_mission_on_px4_sitl(tmp_path) -> None:
    from eaglemission.missions.emulated import run_emulated

    cfg = load_config()
    out = run_emulated(cfg, url=os.environ[ENV_PX4_URL], log_path=tmp_path / "px4.jsonl",
                       connect_timeout_s=30.0)
    r = out.result
    # PREFLIGHT read PX4's own failsafe parameters back
    assert r.failsafe_params is not None
    assert {"COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT"} <= set(r.failsafe_params)
    # the flight ends in DONE or in a configured safe action, never in an active state
    assert r.final_state in ("DONE", "FAILSAFE")
    if r.final_state == "FAILSAFE":
        assert r.action in ("hold", "return", "land", "release"), r.reason
    assert "TAKEOFF" in [s for _, s, _ in r.states]
