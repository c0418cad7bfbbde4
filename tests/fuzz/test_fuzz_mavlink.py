"""Fuzzing the MAVLink receive paths (tests/fuzz/fuzz_mavlink.py): random, cut, corrupted and
reordered MAVLink into the emulator; MAVSDK's HIL_STATE_QUATERNION JSON into HilTruth."""

from __future__ import annotations

import random

from eaglemission.drivers.vehicles.mavsdk.hil_truth import HilTruth
from fuzz_mavlink import EmulatorRig, check_hil, check_stream, random_hil_json, random_stream
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])


@settings(FUZZ, max_examples=25)
@given(st.randoms(use_true_random=False))
def test_mutated_mavlink_streams_never_break_the_emulator(rand: random.Random) -> None:
    rig = EmulatorRig.new()
    try:
        for _ in range(3):
            assert check_stream(rig, random_stream(rand)) == "handled"
    finally:
        rig.close()


@settings(FUZZ, max_examples=40)
@given(st.lists(st.binary(max_size=300), max_size=6))
def test_random_bytes_never_break_the_emulator(chunks: list[bytes]) -> None:
    rig = EmulatorRig.new()
    try:
        assert check_stream(rig, [b"\xfd" + c for c in chunks]) == "handled"
    finally:
        rig.close()


@settings(FUZZ, max_examples=80)
@given(st.randoms(use_true_random=False))
def test_hil_state_json_is_taken_or_counted(rand: random.Random) -> None:
    truth = HilTruth()
    for i in range(5):
        assert check_hil(truth, 1000 * (i + 1), random_hil_json(rand)) in ("taken", "rejected")


def test_deeply_nested_hil_json_is_counted_not_raised() -> None:
    """A fuzzing case: ``[[[[...`` is counted by HilTruth.on_message, not a RecursionError out
    of it."""
    truth = HilTruth()
    assert check_hil(truth, 1, "[" * 100_000) == "rejected" and truth.errors == 1


def test_a_non_finite_offboard_setpoint_is_ignored_by_the_emulator() -> None:
    """A fuzzing case: SET_POSITION_TARGET_LOCAL_NED with z = -inf is ignored, not a handler
    error (Setpoint.down_m must be finite) logged as "emulator: cannot handle"."""
    from eaglemission.lab.vehicles.emulator.dialect import M

    rig = EmulatorRig.new()
    try:
        msg = M.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0, 1.0, -1.0, float("-inf"), 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, float("nan"), 0.0)
        data = msg.pack(M.MAVLink(None, srcSystem=255, srcComponent=190))
        assert check_stream(rig, [data]) == "handled"
        assert rig.emulator.autopilot.setpoint is None
    finally:
        rig.close()
