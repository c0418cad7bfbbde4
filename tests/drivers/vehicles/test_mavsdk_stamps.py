"""The mavsdk driver's autopilot stamps: every ATTITUDE_QUATERNION sample's ``time_boot_ms``
(MAVSDK's ``Quaternion.timestamp_us``) is judged as it arrives (copies and older samples
refused with a ``time_base`` event, a clock jump re-anchored), and the states the mission reads
carry an autopilot time that never goes back between two newer states. The MAVSDK sample
objects are MAVSDK's own classes; the emulator's streams never repeat a sample's stamp."""

from __future__ import annotations

from typing import Any

from eaglemission.drivers.vehicles.mavsdk.support import MavsdkVehicleConfig
from eaglemission.drivers.vehicles.mavsdk.telemetry import MavsdkTelemetry
from eaglemission.lab.vehicles.emulator.messages import Streams

MS = 1_000_000


def _telemetry() -> tuple[MavsdkTelemetry, list[tuple[str, str, Any]]]:
    events: list[tuple[str, str, Any]] = []
    tel = MavsdkTelemetry(MavsdkVehicleConfig(), lambda k, t, d: events.append((k, t, d)),
                          lambda mode, source: None)
    tel.now_ns = lambda: 0
    return tel, events


def _sample(tel: MavsdkTelemetry, receipt_ms: int, boot_ms: int, w: float = 1.0) -> None:
    from mavsdk.plugins.telemetry.telemetry import (
        PositionNed,
        PositionVelocityNed,
        Quaternion,
        VelocityNed,
    )

    tel.receive("position_velocity_ned", receipt_ms * MS,
                PositionVelocityNed(PositionNed(1.0, 2.0, -3.0), VelocityNed(0.0, 0.0, 0.0)))
    tel.receive("attitude_quaternion", receipt_ms * MS + 1,
                Quaternion(w, 0.0, 0.0, 0.0, boot_ms * 1000))


def test_copies_and_older_samples_are_refused_with_an_event() -> None:
    tel, events = _telemetry()
    _sample(tel, 100, 5000)
    _sample(tel, 120, 5020, w=0.9)
    _sample(tel, 125, 5020, w=0.5)  # the same sample again (a duplicating link)
    _sample(tel, 130, 5000, w=0.3)  # an older one (a reordering link)
    assert tel.cache.attitude_q[0] == 0.9, "the cache keeps the newest sample"
    problems = [d["problem"] for k, _, d in events if k == "time_base"]
    assert problems == ["telemetry_duplicate", "telemetry_out_of_order"]


def test_a_clock_jump_is_reported_and_re_anchored() -> None:
    tel, events = _telemetry()
    _sample(tel, 100, 60_000)
    _sample(tel, 120, 10_000)  # 50 s back
    assert tel.cache.attitude_autopilot_ns == 10_000 * MS
    assert [d["problem"] for k, _, d in events if k == "time_base"] == ["autopilot_clock_jump"]
    state = tel.build_state(130 * MS)
    assert state is not None and state.autopilot_time_ns is not None
    assert state.autopilot_time_ns < 11_000 * MS, "the jump reaches the mission's own check"


def test_states_carry_autopilot_time_that_never_goes_back() -> None:
    tel, _ = _telemetry()
    _sample(tel, 100, 5000)
    late = tel.build_state(119 * MS)  # a position sample 19 ms after the attitude
    _sample(tel, 121, 5018)  # the next attitude, 18 ms later on the autopilot's clock
    nxt = tel.build_state(121 * MS + 1)
    assert late is not None and nxt is not None
    assert late.autopilot_time_ns == 5019 * MS - 1
    assert nxt.autopilot_time_ns is not None and nxt.autopilot_time_ns > late.autopilot_time_ns
    assert tel.build_state(121 * MS + 1).autopilot_time_ns == nxt.autopilot_time_ns  # stable


def test_no_attitude_stamp_means_no_autopilot_time() -> None:
    tel, _ = _telemetry()
    from mavsdk.plugins.telemetry.telemetry import PositionNed, PositionVelocityNed, VelocityNed

    tel.receive("position_velocity_ned", MS,
                PositionVelocityNed(PositionNed(0.0, 0.0, 0.0), VelocityNed(0.0, 0.0, 0.0)))
    state = tel.build_state(MS)
    assert state is not None and state.autopilot_time_ns is None


def test_the_emulator_never_sends_a_sample_twice() -> None:
    streams = Streams({"ATTITUDE_QUATERNION": 50.0, "HEARTBEAT": 1.0})
    streams.due(0.0, 0)
    assert "ATTITUDE_QUATERNION" in streams.due(0.03, 30)
    assert "ATTITUDE_QUATERNION" not in streams.due(0.06, 30)  # its simulation lagged
    assert "ATTITUDE_QUATERNION" in streams.due(0.07, 31)  # out as soon as a new sample exists
