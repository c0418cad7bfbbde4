"""Recorded PX4 v1.16 fact: what the downward rangefinder reports on ground contact (scenario
g of ``../shared/data/px4_sitl_tlogs``; skipped when absent).

Fact 29 (README of the recordings): a hold "0.7 m above the ground" by the EKF put the vehicle
on the ground for 13 s; SIH let it sink up to 0.14 m below its resting height, and
DISTANCE_SENSOR read 0 at the first contact, then 65523-65535 cm: the negative range wrapped
around in PX4's ``uint16`` (SIH's sensor: min_distance 0, max_distance 10000 cm, no noise,
``height / cos(tilt)`` truncated to whole cm). A driver must read those as "no reading".
"""

from __future__ import annotations

import bisect
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from eaglemission.drivers.vehicles.mavsdk.support import downward_range_m
from eaglemission.lab.vehicles.emulator.config import PX4_SIH_RANGEFINDER, distance_sensor_cm
from emulator_support import scenario
from test_px4_recorded_facts import Gcs, make_emulator


def _cos_tilt(q: Any) -> float:
    """cos of the angle between the body's down axis and the vertical (w, x, y, z)."""
    _, x, y, _ = (float(v) for v in q)
    return 1.0 - 2.0 * (x * x + y * y)


def recorded_contact_samples(tlogs: Path) -> list[tuple[float, float, int, int, int]]:
    """Scenario g: (truth height m, cos tilt, current, min, max cm) of every DISTANCE_SENSOR
    sent with the truth height below 0.1 m (on or near the ground), the truth interpolated at
    the sample's receive time."""
    px4_msgs, _, _ = scenario(tlogs, "g")
    truth = [(t, m.alt / 1000.0, m.attitude_quaternion) for t, m in px4_msgs
             if m.get_type() == "HIL_STATE_QUATERNION"]
    ground = truth[0][1]
    times = [t for t, _, _ in truth]
    out = []
    for t, m in px4_msgs:
        if m.get_type() != "DISTANCE_SENSOR":
            continue
        i = bisect.bisect_left(times, t)
        if i == 0 or i >= len(times):
            continue
        (ta, ha, _), (tb, hb, qb) = truth[i - 1], truth[i]
        h = ha + (hb - ha) * (t - ta) / (tb - ta) - ground
        if h < 0.1:
            out.append((h, _cos_tilt(qb), int(m.current_distance), int(m.min_distance),
                        int(m.max_distance)))
    return out


def _cm_apart(a: int, b: int) -> int:
    d = abs(a - b) % 65536
    return min(d, 65536 - d)


def test_fact_rangefinder_on_contact_reads_0_then_wraps_to_655xx_cm(px4_tlogs: Path) -> None:
    rec = recorded_contact_samples(px4_tlogs)
    sunk = [s for s in rec if s[0] < -0.02]
    assert len(sunk) > 500 and min(s[0] for s in sunk) < -0.13  # recorded: down to -0.136 m
    assert {s[2] for s in sunk} <= set(range(65523, 65536))  # recorded 65523-65535 cm
    assert {(s[3], s[4]) for s in rec} == {(0, 10000)}  # SIH: min 0, max 100 m
    assert any(s[2] == 0 and abs(s[0]) < 0.005 for s in rec)  # 0 at the contact itself
    ours = [distance_sensor_cm(-h, cos_t, PX4_SIH_RANGEFINDER, 0.0) for h, cos_t, *_ in rec]
    assert {(lo, hi) for _, lo, hi in ours} == {(0, 10000)}
    # the same reading from the same truth (1 cm: truth interpolated at receive time)
    off = [_cm_apart(o[0], s[2]) for o, s in zip(ours, rec, strict=True)]
    assert max(off) <= 2 and sum(x > 1 for x in off) <= 0.02 * len(off), (
        f"{sum(x > 1 for x in off)} of {len(off)} samples more than 1 cm off; e.g. "
        f"{[(round(s[0], 3), o[0], s[2]) for o, s in zip(ours, rec, strict=True)][:5]}")


def test_fact_emulator_on_the_ground_sends_what_sih_sends(px4_tlogs: Path) -> None:
    """Before takeoff (recorded g, t = 0-2 s): current 0, min 0, max 10000 cm, as our emulator
    with PX4 SIH's rangefinder (the landed vehicle rests at height 0: it does not sink)."""
    first = recorded_contact_samples(px4_tlogs)[:20]
    assert {s[2:] for s in first} == {(0, 0, 10000)}
    emu = make_emulator(speedup=2.0)
    emu = type(emu)(emu.config.model_copy(update={"rangefinder": PX4_SIH_RANGEFINDER}), record=True)
    with Gcs(emu) as gcs:
        got = gcs.wait(lambda: gcs.out("DISTANCE_SENSOR")[5:], 5.0, "DISTANCE_SENSOR")
    assert {(m.current_distance, m.min_distance, m.max_distance) for _, _, m in got} == {(0, 0, 10000)}


def test_fact_driver_reads_contact_and_wrapped_ranges_as_no_reading(px4_tlogs: Path) -> None:
    """MAVSDK 4.1 hands DISTANCE_SENSOR over in metres (cm / 100); PITCH_270 = down."""
    def sample(cur: int, lo: int, hi: int) -> SimpleNamespace:
        return SimpleNamespace(current_distance_m=cur / 100.0, minimum_distance_m=lo / 100.0,
                               maximum_distance_m=hi / 100.0,
                               orientation=SimpleNamespace(roll_deg=0.0, pitch_deg=270.0, yaw_deg=0.0))

    rec = recorded_contact_samples(px4_tlogs)
    on_ground = [s for s in rec if s[2] == 0 or s[2] > s[4]]
    assert len(on_ground) > 600
    assert all(downward_range_m(sample(*s[2:])) is None for s in on_ground)
    flying = [s for s in rec if 0 < s[2] <= s[4] and s[0] > 0.05]
    assert flying and all(downward_range_m(sample(*s[2:])) == s[2] / 100.0 for s in flying)
    assert math.isclose(downward_range_m(sample(69, 0, 10000)) or 0.0, 0.69)
