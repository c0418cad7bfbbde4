"""The MAVSDK driver's ``ground_truth_altitude``: what HIL_STATE_QUATERNION's ``alt`` holds.

PX4 SIH sends the true altitude AMSL (recorded: ``../shared/data/px4_sitl_tlogs``, scenario d);
with jMAVSim PX4 passes on jMAVSim's NED z (0 on the ground, -2891 mm at 2.89 m up). The
jMAVSim samples below were recorded from PX4 v1.16.0 + jMAVSim (headless, lockstep) through
MAVSDK's MavlinkDirect during a take-off to 3 m: every 10th message (5 Hz) from just before the
lift-off to 2.89 m, (ms after the first message, lat, lon degE7, alt mm, vx, vy, vz cm/s,
attitude (w, x, y, z)).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from eaglemission.drivers.vehicles.mavsdk.hil_truth import AltitudeSense, HilTruth

try:  # tests/ is not a package
    from emulator_support import flying_pair, scenario, wait_for
except ImportError:  # pragma: no cover
    from .emulator_support import flying_pair, scenario, wait_for  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[3]

JMAVSIM_TAKEOFF = [
    (7580, 473977418, 85455937, 0, 0, 0, 0, (1.0, 0.0, 0.0, 0.0)),
    (7780, 473977420, 85455940, -1, 0, 0, -2, (1.0, 0.0042, 0.0019, 0.0)),
    (7980, 473977419, 85455937, -15, -1, 2, -13, (1.0, 0.0048, 0.0024, 0.0001)),
    (8180, 473977420, 85455939, -60, -2, 3, -33, (1.0, 0.0017, 0.0011, 0.0001)),
    (8380, 473977419, 85455940, -145, -2, 4, -51, (1.0, -0.0003, 0.0004, 0.0)),
    (8580, 473977417, 85455940, -265, -2, 3, -68, (1.0, -0.0008, -0.0002, -0.0)),
    (8780, 473977417, 85455945, -417, -2, 3, -83, (1.0, -0.0015, -0.0002, -0.0001)),
    (8984, 473977415, 85455943, -598, -2, 2, -97, (1.0, -0.0023, -0.0007, -0.0001)),
    (9185, 473977418, 85455943, -808, -1, 1, -112, (1.0, -0.0023, -0.0008, 0.0)),
    (9384, 473977417, 85455946, -1041, -1, 0, -117, (1.0, -0.0021, -0.001, 0.0)),
    (9584, 473977417, 85455946, -1272, -1, 0, -111, (1.0, -0.0024, -0.0011, 0.0001)),
    (9784, 473977415, 85455948, -1487, 0, -1, -103, (1.0, -0.0022, -0.0009, 0.0001)),
    (9988, 473977415, 85455946, -1688, 0, -1, -97, (1.0, -0.0017, -0.0004, -0.0)),
    (10188, 473977417, 85455942, -1876, 0, -2, -91, (1.0, -0.0013, -0.0006, -0.0)),
    (10388, 473977418, 85455943, -2052, 0, -2, -84, (1.0, -0.0015, -0.0005, -0.0001)),
    (10588, 473977414, 85455942, -2215, 0, -3, -77, (1.0, -0.0015, -0.0003, -0.0001)),
    (10788, 473977417, 85455940, -2363, 0, -3, -70, (1.0, -0.001, -0.0005, -0.0001)),
    (10988, 473977417, 85455940, -2492, 0, -4, -55, (1.0, -0.0002, -0.0006, -0.0001)),
    (11188, 473977414, 85455939, -2578, 0, -4, -31, (1.0, 0.0001, -0.0009, -0.0002)),
    (11392, 473977414, 85455937, -2626, 0, -4, -18, (1.0, 0.0004, -0.0006, -0.0002)),
    (11592, 473977414, 85455937, -2661, 1, -3, -16, (1.0, 0.0009, -0.0005, 0.0002)),
    (11792, 473977417, 85455939, -2694, 1, -3, -14, (1.0, 0.0013, -0.0008, 0.0009)),
    (11992, 473977415, 85455937, -2724, 1, -2, -14, (1.0, 0.0017, -0.0004, 0.0016)),
    (12192, 473977415, 85455933, -2752, 1, -2, -12, (1.0, 0.0014, -0.0008, 0.0021)),
    (12392, 473977418, 85455934, -2776, 2, -1, -11, (1.0, 0.0016, -0.0008, 0.0023)),
    (12592, 473977418, 85455934, -2797, 2, 0, -9, (1.0, 0.0015, -0.0007, 0.0026)),
    (12796, 473977420, 85455934, -2817, 2, 0, -9, (1.0, 0.0017, -0.0003, 0.0028)),
    (12995, 473977420, 85455931, -2835, 2, 0, -8, (1.0, 0.0014, 0.0003, 0.0029)),
    (13200, 473977420, 85455934, -2851, 2, 1, -7, (1.0, 0.0008, 0.0005, 0.0028)),
    (13400, 473977420, 85455934, -2866, 2, 1, -7, (1.0, 0.0006, 0.0006, 0.0027)),
    (13600, 473977421, 85455936, -2879, 2, 1, -6, (1.0, 0.0006, 0.0011, 0.0025)),
    (13800, 473977420, 85455934, -2891, 2, 2, -4, (1.0, 0.0005, 0.001, 0.0024)),
]


def _feed(truth: HilTruth, samples: list[tuple[int, dict[str, Any]]]) -> None:
    """Each (stamp ns, fields) as MAVSDK's MavlinkDirect hands it over: JSON text."""
    for stamp_ns, fields in samples:
        truth.on_message(stamp_ns, json.dumps(fields))


def _jmavsim() -> list[tuple[int, dict[str, Any]]]:
    return [(ms * 1_000_000, {"lat": lat, "lon": lon, "alt": alt, "vx": vx, "vy": vy, "vz": vz,
                              "attitude_quaternion": list(q), "time_usec": 0})
            for ms, lat, lon, alt, vx, vy, vz, q in JMAVSIM_TAKEOFF]


def test_jmavsim_take_off_read_as_ned_z_climbs_to_its_true_height() -> None:
    problems: list[str] = []
    truth = HilTruth(altitude="ned_z", on_problem=problems.append)
    _feed(truth, _jmavsim())
    heights = [-s.position_ned_m[2] for s in truth.trajectory()]
    assert heights[0] == 0.0 and heights[-1] == pytest.approx(2.891)
    assert min(heights) >= 0.0
    assert truth.sense.verdict is True and problems == [] and truth.problem is None
    assert truth.description.startswith("HIL_STATE_QUATERNION")  # the run header's wording


def test_jmavsim_take_off_read_as_amsl_is_reported_once_with_the_fix() -> None:
    problems: list[str] = []
    truth = HilTruth(altitude="amsl", on_problem=problems.append)
    _feed(truth, _jmavsim())
    _feed(truth, [(t + 10_000_000_000, f) for t, f in _jmavsim()])  # a second climb
    assert -truth.trajectory()[-1].position_ned_m[2] == pytest.approx(-2.891)  # underground
    assert len(problems) == 1 and truth.sense.verdict is False
    assert "`ground_truth_altitude: ned_z`" in problems[0] and "read as amsl" in problems[0]


def test_recorded_sih_flight_reads_as_amsl_and_not_as_ned_z(px4_tlogs: Path) -> None:
    px4_msgs, _, _ = scenario(px4_tlogs, "d")
    samples = [(int(t * 1e9), {k: v for k, v in m.to_dict().items() if k != "mavpackettype"})
               for t, m in px4_msgs if m.get_type() == "HIL_STATE_QUATERNION"]
    top_m = (max(f["alt"] for _, f in samples) - samples[0][1]["alt"]) / 1000.0
    assert top_m > 5.0
    amsl = HilTruth(altitude="amsl")
    _feed(amsl, samples)
    assert amsl.errors == 0 and amsl.sense.verdict is True and amsl.problem is None
    assert max(-s.position_ned_m[2] for s in amsl.trajectory()) == pytest.approx(top_m, abs=0.01)
    wrong = HilTruth(altitude="ned_z")
    _feed(wrong, samples)
    assert wrong.sense.verdict is False
    assert wrong.problem is not None and "`ground_truth_altitude: amsl`" in wrong.problem


def test_the_verdict_waits_for_a_metre_of_vertical_travel() -> None:
    sense = AltitudeSense()
    # on the ground, then hovering: no vertical travel, no verdict however long
    for k in range(500):
        assert sense.add(k * 0.02, 0.0, 0.0) is None
    # climbing at 1 m/s with the altitude falling: decided after 1 m, not before
    verdicts = [sense.add(10.0 + k * 0.02, -0.02 * k, 1.0) for k in range(1, 80)]
    decided = [k for k, v in enumerate(verdicts, start=1) if v is not None]
    assert decided == [50] and verdicts[49] is False
    # gaps longer than 0.5 s are not counted (a lost link, not a jump of the altitude)
    gap = AltitudeSense()
    assert [gap.add(k * 1.0, float(k), 1.0) for k in range(5)] == [None] * 5
    assert gap.travelled_m == 0.0


def test_an_unknown_altitude_convention_is_refused() -> None:
    with pytest.raises(ValueError, match="amsl, ned_z"):
        HilTruth(altitude="agl")


def test_validate_names_the_param_and_its_choices(tmp_path: Path) -> None:
    data = yaml.safe_load((REPO / "configs" / "px4_jmavsim.yaml").read_text())
    data["vehicle"]["params"]["ground_truth_altitude"] = "agl"
    f = tmp_path / "m.yaml"
    f.write_text(yaml.safe_dump(data))
    r = subprocess.run([sys.executable, "-m", "eaglemission.cli", "validate", str(f)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert ("vehicle.params.ground_truth_altitude: must be one of 'amsl' or 'ned_z', got 'agl'"
            in r.stderr)


async def test_driver_warns_when_the_declared_altitude_is_wrong() -> None:
    """The emulator sends AMSL (as PX4 SIH); a vehicle declared ``ned_z`` is told once it
    climbs: a ``truth`` event naming the param, and no event with the right declaration."""
    for declared, expect in (("ned_z", True), ("amsl", False)):
        async with flying_pair(4.0, vehicle={"ground_truth_altitude": declared}) as (emu, v, _):
            await v.arm()
            await v.takeoff(3.0)
            await wait_for(lambda v=v: -v.state().position_ned_m[2] > 2.5, 20.0, "climbed")
            truth = v.ground_truth()
            assert truth is not None and truth.sense.verdict is not None
            events = [e for e in v.events() if e.kind == "truth"]
            assert bool(events) is expect, (declared, events)
            if expect:
                assert "`ground_truth_altitude: amsl`" in events[0].text
