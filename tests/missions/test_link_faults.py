"""The link's timing faults (link_delay, link_duplicate, link_reorder, autopilot_clock_jump) injected at the simulated vehicle's telemetry boundary in short
virtual-time flights: each ends in its expected outcome (docs/faults.md) with no envelope
violation and a ``fault_detected`` record of the mission noticing; a delay beyond
``safety.max_telemetry_age_s`` ends in the link-loss failsafe."""

from __future__ import annotations

from pathlib import Path

import pytest
from eaglemission.lab.faults.outcomes import OUTCOMES, expected_action
from eaglemission.missions.log import read_log
from fault_harness import Fault, fly_with_faults
from mission_helpers import variant

from eaglemission.config import MissionFile

TOLERABLE = {
    "link_delay": Fault("link_delay", "COARSE_APPROACH", 0.5, 2.0, 0.3),
    "link_duplicate": Fault("link_duplicate", "COARSE_APPROACH", 0.5, 2.0),
    "link_reorder": Fault("link_reorder", "COARSE_APPROACH", 0.5, 2.0),
    "autopilot_clock_jump": Fault("autopilot_clock_jump", "COARSE_APPROACH", 0.5, 1.0, -30.0),
}


def _detected(recs: list[dict], what: str) -> list[dict]:
    t_inj = min(r["t_ns"] for r in recs if r["kind"] == "fault_injected")
    return [r for r in recs if r["kind"] == "fault_detected" and r["what"] == what
            and r["t_ns"] >= t_inj]


@pytest.mark.parametrize("kind", sorted(TOLERABLE))
def test_a_tolerable_link_fault_still_completes(fast_config: MissionFile, tmp_path: Path,
                                                kind: str) -> None:
    fault = TOLERABLE[kind]
    assert expected_action(kind, fast_config) == "complete"
    log = tmp_path / "f.jsonl"
    out = fly_with_faults(fast_config, [fault], log_path=log)
    states = [s for _, s, _ in out.result.states]
    assert "GRASP_READY" in states and out.result.final_state == "DONE", out.result.reason
    assert out.evaluation.violations == []
    recs = list(read_log(log))
    assert any(r["kind"] == "fault_injected" and r["fault"] == kind for r in recs)
    what = OUTCOMES[kind].detected_by[0]
    found = _detected(recs, what)
    assert found, f"{kind}: no fault_detected {what}"
    assert found[0]["response"] and found[0]["text"]


def test_a_delay_beyond_the_age_bound_ends_in_the_link_loss_action(
        fast_config: MissionFile, tmp_path: Path) -> None:
    """2 s late telemetry for 6 s: stale beyond safety.max_telemetry_age_s (0.5 s), a lost
    link after safety.link_loss_timeout_s more."""
    fault = Fault("link_delay", "COARSE_APPROACH", 0.5, 6.0, 2.0)
    log = tmp_path / "f.jsonl"
    out = fly_with_faults(fast_config, [fault], log_path=log)
    action = fast_config.safety.link_loss_action
    assert out.result.final_state == "FAILSAFE" and out.result.action == action, \
        out.result.reason
    assert "link lost" in out.result.reason
    assert out.evaluation.violations == []
    assert _detected(list(read_log(log)), "telemetry_stale")


def test_a_slow_autopilot_clock_is_not_a_lost_link(fast_config: MissionFile,
                                                   tmp_path: Path) -> None:
    """PX4 SITL's clock runs up to 2 % slow against the host's under the mission's load (a
    local SITL): with the age judged on a fixed anchor the telemetry would read 0.5 s old after
    25 s of flight and the mission fail safe over a healthy link."""
    params = {**fast_config.vehicle.params, "autopilot_clock_rate": 0.98}
    cfg = variant(fast_config, vehicle={"params": params})
    log = tmp_path / "slow.jsonl"
    out = fly_with_faults(cfg, [], log_path=log)
    assert out.result.final_state == "DONE", out.result.reason
    recs = list(read_log(log))
    assert not [r for r in recs if r["kind"] == "fault_detected"
                and r["what"] in ("telemetry_stale", "telemetry_late")]
