"""A whole simulated mission under bursts of hostile telemetry (tests/fuzz/fuzz_mission.py):
it ends safe, nothing it commands leaves the envelope. Many seeds: benchmarks/fuzz.py
--missions N."""

from __future__ import annotations

from fuzz_mission import check_mission

from eaglemission.config import load_config


def test_nan_attitude_and_position_bursts_end_safe_not_in_an_exception() -> None:
    """Fuzzing seed 3 (4 and 6 alike): a NaN attitude must not reach the grasp check
    (quat_to_R: ValueError) nor a NaN position the rangefinder plane (ValueError): the mission
    ends in its safe action, not in an unexpected error (exit 1)."""
    outcome = check_mission(load_config(None), 3)
    assert outcome.split(":")[0] in ("DONE", "FAILSAFE", "GRASP_READY")
