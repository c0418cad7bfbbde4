"""Injected faults (a mission file's ``faults:`` section) end in their expected outcome
(docs/faults.md): tolerable ones, several per short closed-loop run, still reach GRASP_READY
and DONE; an intolerable one ends in its configured safe action on the ground. Each fault is
logged as injected and the mission's log shows it noticed. Link, GPS, battery, pilot, drop
and occlusion faults: tests/missions/test_closed_loop.py."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from eaglemission.lab.campaign.faults import grasped_elsewhere, noticed
from eaglemission.lab.faults.outcomes import expected_action
from eaglemission.missions.log import read_log
from fault_harness import Fault, fly_with_faults

from eaglemission.config import MissionFile, TargetConfig

TOLERABLE = {
    "camera_and_world": [Fault("camera_freeze", "COARSE_APPROACH", 0.3, 0.5),
                         Fault("corrupted_frame", "COARSE_APPROACH", 1.2, 0.06),
                         Fault("wind_gust", "COARSE_APPROACH", 2.0, 2.0, 0.3),
                         Fault("truncated_frame", "FINE_APPROACH", 0.2, 0.06),
                         Fault("exposure_jump", "FINE_APPROACH", 1.0, 0.3, 3.0)],
    "perception_and_link": [Fault("command_denied", "CRUISE", 0.5),
                            Fault("detector_exception", "COARSE_APPROACH", 0.3, 0.4),
                            Fault("nan_map", "COARSE_APPROACH", 1.2, 0.4),
                            Fault("degenerate_corners", "FINE_APPROACH", 0.3, 0.4),
                            Fault("pose_flip", "FINE_APPROACH", 1.0, 0.5)],
}


def _injected_and_noticed(recs: list[dict], faults: list[Fault]) -> None:
    injected = {r["fault"]: r["t_ns"] for r in recs if r["kind"] == "fault_injected"}
    for f in faults:
        assert f.kind in injected, f"{f.kind}: never injected"
        assert noticed(recs, f.kind, injected[f.kind]), f"{f.kind}: the mission did not notice"


@pytest.mark.parametrize("group", sorted(TOLERABLE))
def test_tolerable_faults_still_complete(fast_config: MissionFile, tmp_path: Path,
                                         group: str) -> None:
    faults = TOLERABLE[group]
    assert all(expected_action(f.kind, fast_config) == "complete" for f in faults)
    log = tmp_path / "f.jsonl"
    out = fly_with_faults(fast_config, faults, log_path=log)
    states = [s for _, s, _ in out.result.states]
    assert "GRASP_READY" in states and out.result.final_state == "DONE", out.result.reason
    assert out.evaluation.violations == []
    _injected_and_noticed(list(read_log(log)), faults)


def test_a_camera_clock_jump_ends_in_the_camera_failure_action(fast_config: MissionFile,
                                                               tmp_path: Path) -> None:
    """Frames stamped 20 s off are refused; with no usable frame the camera watch fires."""
    fault = Fault("camera_clock_jump", "CRUISE", 0.5, 1.0, 20.0)
    action = expected_action(fault.kind, fast_config)
    log = tmp_path / "f.jsonl"
    out = fly_with_faults(fast_config, [fault], log_path=log)
    assert out.result.final_state == "FAILSAFE" and out.result.action == action, \
        out.result.reason
    assert "camera failure" in out.result.reason
    assert out.evaluation.ended_safe and out.evaluation.landed, out.evaluation.explanation
    assert out.evaluation.violations == []
    recs = list(read_log(log))
    _injected_and_noticed(recs, [fault])
    assert any(r["kind"] == "fault_detected" and r["what"] == "frame_stamp" for r in recs)


def test_campaign_with_faults_ends_each_run_in_its_expected_outcome(
        fast_config: MissionFile, tmp_path: Path) -> None:
    cfg = tmp_path / "fast.yaml"
    cfg.write_text(yaml.safe_dump(fast_config.model_dump(mode="json")))
    proc = subprocess.run([sys.executable, "-m", "eaglemission.cli", "campaign", str(cfg),
                           "--faults", "all", "--runs", "2", "--seed", "3", "--workers", "2"],
                          capture_output=True, text=True, timeout=600)
    assert "per fault kind" in proc.stdout, proc.stderr[-2000:]
    line = next(x for x in proc.stdout.splitlines() if "runs in their expected outcome" in x)
    ok, total = (int(x) for x in line.split(":")[1].split("/"))
    assert (ok, total) == (2, 2) and proc.returncode == 0, proc.stdout[-3000:]
    bad = subprocess.run([sys.executable, "-m", "eaglemission.cli", "campaign", str(cfg),
                          "--faults", "camera_dorp", "--runs", "1"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "camera_dorp" in bad.stderr


def test_a_grasp_beyond_the_target_is_another_object() -> None:
    """GRASP_READY + DONE on a distractor of the target's colour 11.2 m away (the square box of
    tests/missions/test_candidate_rejection.py) is not a completed tolerable fault."""
    box = TargetConfig(length_m=0.3, width_m=0.2)
    assert grasped_elsewhere(None, box) == "" and grasped_elsewhere(0.069, box) == ""
    assert grasped_elsewhere(0.15, box) == ""  # on the box, if not precise (the evaluator's)
    why = grasped_elsewhere(11.238, box)
    assert "11.24 m from the true target" in why and "another object" in why


def test_the_fault_table_counts_a_grasp_elsewhere_as_not_on_the_target(
        capsys: pytest.CaptureFixture[str]) -> None:
    from eaglemission.lab.campaign.faults import print_fault_table

    def run(i: int, failure: str) -> dict[str, object]:
        return {"run": i, "fault": "command_denied", "expected": "complete",
                "final_state": "DONE", "reached_grasp_ready": True, "violations": [],
                "expected_outcome": not failure, "fault_failure": failure,
                "log_complete": True, "time_to_safe_s": None, "explanation": ""}

    elsewhere = grasped_elsewhere(11.238, TargetConfig(length_m=0.4, width_m=0.25))
    assert print_fault_table([run(0, ""), run(1, elsewhere)]) == 1
    out = capsys.readouterr().out
    assert "GRASP_READY + DONE): 2/2 (100%); on the target: 1/2 (50.0%)" in out
