"""The mission through MAVSDK against the emulator when the link goes down just as offboard
starts: the driver's bounded wait for OFFBOARD runs out with a ``TimeoutError_``, which the
actuator must take for a refused command (not crash the mission with "unhandled errors in a
TaskGroup"). It must end in the link-loss action, with the log complete and no envelope
violation."""

from __future__ import annotations

from pathlib import Path

import pytest
from eaglemission.lab.campaign.emulator import fly_on_emulator
from eaglemission.missions.log import read_log
from fault_harness import Fault, with_faults

from eaglemission.config import MissionFile


@pytest.mark.slow
@pytest.mark.parametrize("delay_s", [0.0, 0.3])
def test_a_link_lost_as_offboard_starts_ends_in_the_link_loss_action(
        fast_config: MissionFile, tmp_path: Path, delay_s: float) -> None:
    cfg = with_faults(fast_config, [Fault("link_loss", "CRUISE", delay_s, 3.0)])
    log = tmp_path / "run.jsonl"
    out = fly_on_emulator(cfg, log_path=log, keep_log=True)
    assert out.result.final_state == "FAILSAFE", out.result.reason
    assert out.result.action == fast_config.safety.link_loss_action, out.result.reason
    assert out.evaluation.violations == []
    recs = list(read_log(log))
    end = [r for r in recs if r["kind"] == "end"]
    assert len(end) == 1 and end[0]["completed"] is True
