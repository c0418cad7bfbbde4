"""The mission on a real PX4 v1.16 SITL, flown by ``eaglemission run`` with a ``mavsdk``
vehicle: ``configs/px4_sitl.yaml`` on SIH, ``configs/px4_jmavsim.yaml`` on jMAVSim; the
synthetic cameras render from the ground truth PX4 streams (HIL_STATE_QUATERNION, requested by
the driver).

The PX4 comes from the ``px4_sitl`` fixture (tests/conftest.py): a fresh instance when
``EAGLEMISSION_PX4_BUILD`` is set, else the one at ``EAGLEMISSION_PX4_URL``; skipped when
neither is set. It asserts what a field team needs, judged on the simulator's truth: PX4's
failsafe parameters read, a clean landing, no envelope violation; and GRASP_READY within
tolerance, then DONE. On SIH the last part is an expected failure: SIH's hover wanders
0.5-0.8 m RMS near the ground (docs/vehicles.md, "PX4 SITL").
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml
from deployment_helpers import REPO, cli, log_records, mission_file, run_env

pytestmark = [pytest.mark.px4, pytest.mark.machine]

CONFIGS = {"sih": "px4_sitl.yaml", "jmavsim": "px4_jmavsim.yaml"}


def test_mission_on_px4_sitl(tmp_path: Path, px4_sitl: Any) -> None:
    base = CONFIGS[px4_sitl.sim]
    params = yaml.safe_load((REPO / "configs" / base).read_text())["vehicle"]["params"]
    mission = mission_file(tmp_path, "px4.yaml", base=base, vehicle={
        "_replace": True, "type": "mavsdk",
        "params": {**params, "url": px4_sitl.url, "connect_timeout_s": 30}})
    p = subprocess.run(cli("run", str(mission), "--yes", "--log", "px4.jsonl"), cwd=tmp_path,
                       capture_output=True, text=True, timeout=900, env=run_env())
    assert "Traceback" not in p.stderr, p.stderr[-3000:]
    assert "ground truth: HIL_STATE_QUATERNION" in p.stdout
    assert "moved against the message's own vertical velocity" not in p.stderr, p.stderr[-3000:]
    recs = log_records(tmp_path / "px4.jsonl")
    params_read = [r for r in recs if r["kind"] == "failsafe_params"]
    assert params_read and {"COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT"} <= set(
        params_read[0]["values"])
    states = [r["new"] for r in recs if r["kind"] == "state"]
    ev = [r for r in recs if r["kind"] == "evaluation"][-1]
    assert ev["judged_on"] == "truth", ev
    assert ev["landed"] and ev["violations"] == [], ev
    if px4_sitl.sim == "sih" and "GRASP_READY" not in states:
        pytest.xfail(f"SIH: no GRASP_READY (states {states}): SIH's hover wanders 0.5-0.8 m "
                     "RMS near the ground")
    assert "GRASP_READY" in states and states[-1] == "DONE", (states, p.stdout[-3000:])
    assert ev["success"], ev
    assert p.returncode == 0
