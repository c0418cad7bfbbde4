"""The mission on a real PX4 v1.16 SITL (SIH), flown by ``eaglemission run`` with a ``mavsdk``
vehicle at ``EAGLEMISSION_PX4_URL`` (e.g. ``udpin://0.0.0.0:14540``); the synthetic cameras
render from PX4's ground truth (HIL_STATE_QUATERNION, requested by the driver).

Skipped unless ``EAGLEMISSION_PX4_URL`` is set. Start a fresh PX4 for each run (parameters and
dataman wiped: README, "Against PX4 SITL"). It asserts what a field team needs: GRASP_READY
within tolerance judged on PX4's ground truth, DONE, a clean landing, no envelope violation.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from deployment_helpers import cli, log_records, mission_file, run_env

from eaglemission.names import ENV_PX4_URL

pytestmark = [pytest.mark.px4, pytest.mark.machine, pytest.mark.skipif(
    not os.environ.get(ENV_PX4_URL), reason=f"no PX4 SITL: set {ENV_PX4_URL}")]


def test_mission_on_px4_sitl(tmp_path: Path) -> None:
    url = os.environ[ENV_PX4_URL]
    mission = mission_file(tmp_path, "px4.yaml", base="px4_sitl.yaml", vehicle={
        "_replace": True, "type": "mavsdk", "params": {"url": url, "connect_timeout_s": 30}})
    p = subprocess.run(cli("run", str(mission), "--yes", "--log", "px4.jsonl"), cwd=tmp_path,
                       capture_output=True, text=True, timeout=900, env=run_env())
    assert "Traceback" not in p.stderr, p.stderr[-3000:]
    assert "ground truth: HIL_STATE_QUATERNION" in p.stdout
    recs = log_records(tmp_path / "px4.jsonl")
    params = [r for r in recs if r["kind"] == "failsafe_params"]
    assert params and {"COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT"} <= set(params[0]["values"])
    states = [r["new"] for r in recs if r["kind"] == "state"]
    ev = [r for r in recs if r["kind"] == "evaluation"][-1]
    assert "GRASP_READY" in states and states[-1] == "DONE", (states, p.stdout[-3000:])
    assert ev["judged_on"] == "truth" and ev["success"], ev
    assert ev["landed"] and ev["violations"] == [], ev
    assert p.returncode == 0
