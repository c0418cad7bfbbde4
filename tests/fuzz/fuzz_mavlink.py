"""Fuzz target: random, truncated, corrupted and reordered MAVLink into the receive paths.

* the emulator's receive path (what :meth:`Px4Emulator.feed` and the UDP reader deliver, handled
  by :meth:`~Px4Emulator.step`): valid messages of the handled kinds with random fields (NaN,
  infinities, out-of-range ids and enums), cut, bit-flipped, interleaved with garbage and
  reordered, fed in random chunks, with the emulator stepped between chunks;
* the ground-truth parser of the MAVSDK driver (:meth:`HilTruth.on_message`, fed the JSON
  MAVSDK's MavlinkDirect hands over).

Property: nothing raises; no handler fails (the emulator logs and swallows handler
exceptions: a logged one counts as a crash here); the emulated vehicle's true state stays
finite; every byte the emulator sends back parses as MAVLink.
"""

from __future__ import annotations

import json
import logging
import math
import random
import struct
from dataclasses import dataclass
from typing import Any

from eaglemission.drivers.vehicles.mavsdk.hil_truth import HilTruth
from eaglemission.lab.vehicles.emulator.dialect import M
from eaglemission.lab.vehicles.emulator.emulator import Px4Emulator
from fuzz_common import FLOATS, FuzzCrash, random_value

TARGET = "mavlink"
LOGGER = "eaglemission.drivers.vehicles"
HANDLED = ("COMMAND_LONG", "COMMAND_INT", "PARAM_SET", "PARAM_REQUEST_READ",
           "PARAM_REQUEST_LIST", "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_REQUEST_LIST",
           "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
           "SET_POSITION_TARGET_LOCAL_NED", "HEARTBEAT", "PING")
OTHERS = tuple(sorted({c.msgname for c in M.mavlink_map.values()} - set(HANDLED)))
COMMAND_IDS = tuple(sorted(M.enums["MAV_CMD"]))
INT_RANGES = {"uint8_t": (0, 255), "int8_t": (-128, 127), "uint16_t": (0, 65535),
              "int16_t": (-32768, 32767), "uint32_t": (0, 2**32 - 1),
              "int32_t": (-2**31, 2**31 - 1), "uint64_t": (0, 2**64 - 1),
              "int64_t": (-2**63, 2**63 - 1)}
CLASSES = {c.msgname: c for c in M.mavlink_map.values()}


def _field(rng: random.Random, name: str, ftype: str, length: int) -> Any:
    def one() -> Any:
        if ftype in ("float", "double"):
            return rng.choice(FLOATS[:12]) if rng.random() < 0.4 else rng.uniform(-1e4, 1e4)
        if ftype == "char":
            return bytes(rng.randrange(256) for _ in range(rng.randrange(length + 1)))
        lo, hi = INT_RANGES[ftype]
        if name == "command":
            return rng.choice(COMMAND_IDS)
        if name in ("target_system", "target_component"):
            return rng.choice((0, 1, 1, 190, 255, rng.randint(lo, hi)))
        if name in ("seq", "count", "param_index", "frame", "type_mask"):
            return rng.choice((0, 1, 2, 3, 7, lo, hi, rng.randint(lo, hi)))
        return rng.choice((lo, hi, 0, 1)) if rng.random() < 0.3 else rng.randint(lo, hi)

    if ftype == "char":
        return one()
    if length:
        return [one() for _ in range(length)]
    return one()


def random_message(rng: random.Random) -> Any:
    """A MAVLink message of a handled kind (mostly) with random field values."""
    name = rng.choice(HANDLED) if rng.random() < 0.85 else rng.choice(OTHERS)
    cls = CLASSES[name]
    values = [_field(rng, f, t, n) for f, t, n in
              zip(cls.fieldnames, cls.fieldtypes, cls.array_lengths)]
    if name == "PARAM_SET" and rng.random() < 0.5:
        values[cls.fieldnames.index("param_id")] = rng.choice(
            (b"MPC_XY_VEL_MAX", b"COM_DL_LOSS_T", b"NAV_DLL_ACT", b"RTL_RETURN_ALT", b"X"))
    return cls(*values)


def random_stream(rng: random.Random, n: int | None = None) -> list[bytes]:
    """Chunks of bytes as a link might deliver them: packed messages, some cut short,
    corrupted or duplicated, garbage between them, reordered, split at random points."""
    mav = M.MAVLink(None, srcSystem=rng.choice((255, 1, 0, 42)), srcComponent=190)
    packets: list[bytes] = []
    for _ in range(n if n is not None else rng.randint(1, 12)):
        try:
            data = random_message(rng).pack(mav)
        except (struct.error, TypeError, ValueError, OverflowError):
            continue  # a value pymavlink cannot even encode never reaches the wire
        op = rng.random()
        if op < 0.1:
            data = data[: rng.randrange(len(data))]
        elif op < 0.2:
            b = bytearray(data)
            for _ in range(rng.randint(1, 4)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            data = bytes(b)
        elif op < 0.25:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(64)))
        elif op < 0.3:
            data = data + data
        packets.append(data)
    if rng.random() < 0.3:
        rng.shuffle(packets)
    blob = b"".join(packets)
    chunks, i = [], 0
    while i < len(blob):
        k = rng.choice((len(blob), rng.randint(1, 300)))
        chunks.append(blob[i:i + k])
        i += k
    if rng.random() < 0.1:
        rng.shuffle(chunks)
    return chunks


class _Failures(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.records: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record.getMessage() + (
            f" ({record.exc_info[0].__name__}: {record.exc_info[1]})" if record.exc_info
            and record.exc_info[0] is not None else ""))


@dataclass
class EmulatorRig:
    """One emulator fed in-process (no threads), its output parsed back."""

    emulator: Px4Emulator
    parser: Any
    failures: _Failures
    out_errors: int = 0
    out_messages: int = 0
    old_level: int = logging.NOTSET

    @classmethod
    def new(cls) -> EmulatorRig:
        emu = Px4Emulator()
        parser = M.MAVLink(None)
        parser.robust_parsing = True
        rig = cls(emu, parser, _Failures())
        emu.set_output(rig.outgoing)
        lg = logging.getLogger(LOGGER)
        rig.old_level = lg.level
        if not lg.isEnabledFor(logging.ERROR):  # a quiet root logger must not hide failures
            lg.setLevel(logging.ERROR)
        lg.addHandler(rig.failures)
        return rig

    def close(self) -> None:
        lg = logging.getLogger(LOGGER)
        lg.removeHandler(self.failures)
        lg.setLevel(self.old_level)
        self.emulator.stop()

    def outgoing(self, data: bytes) -> None:
        self.out_messages += 1
        for msg in self.parser.parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA":
                self.out_errors += 1


def check_stream(rig: EmulatorRig, chunks: list[bytes]) -> str:
    """Feed one stream into the emulator; ``handled`` or :class:`FuzzCrash`."""
    emu = rig.emulator
    try:
        for chunk in chunks:
            emu.feed(chunk)
            emu.step(0.05)
    except Exception as exc:
        raise FuzzCrash(TARGET, f"emulator raised {type(exc).__name__}: {exc}", chunks) from exc
    if rig.failures.records:
        first = rig.failures.records[0]
        rig.failures.records.clear()
        raise FuzzCrash(TARGET, f"emulator handler failed: {first}", chunks)
    if rig.out_errors:
        rig.out_errors = 0
        raise FuzzCrash(TARGET, "the emulator sent bytes that do not parse", chunks)
    snap = emu.snapshot()
    if not all(math.isfinite(v) for v in (*snap.true_position_ned_m, *snap.true_attitude_q)):
        raise FuzzCrash(TARGET, f"the emulated vehicle's state went non-finite: {snap}", chunks)
    return "handled"


# -- HIL_STATE_QUATERNION as MAVSDK hands it over ------------------------------------------
def random_hil_json(rng: random.Random) -> str:
    """The JSON fields of a HIL_STATE_QUATERNION, valid, mutated or not JSON at all."""
    fields: dict[str, Any] = {"attitude_quaternion": [1.0, 0.0, 0.0, 0.0], "lat": 473977418,
                              "lon": 85455938, "alt": 488000, "vx": 0, "vy": 0, "vz": 0}
    k = rng.randrange(5)
    if k == 0:
        return json.dumps(fields)
    if k == 1:
        key = rng.choice(list(fields))
        fields[key] = rng.choice((random_value(rng), math.nan, math.inf, None, [], "x", 1e308))
        return json.dumps(fields)
    if k == 2:
        del fields[rng.choice(list(fields))]
        return json.dumps(fields)
    if k == 3:
        text = json.dumps(fields)
        return text[: rng.randrange(len(text))]
    return rng.choice(("", "null", "[]", "1", '"x"', "[" * 5000, '{"lat": NaN}',
                       json.dumps(random_value(rng))))


def check_hil(truth: HilTruth, stamp_ns: int, text: str) -> str:
    """``on_message`` takes it or counts an error; never raises."""
    before = truth.errors
    try:
        truth.on_message(stamp_ns, text)
        truth.pose_at(stamp_ns)
    except Exception as exc:
        raise FuzzCrash(TARGET, f"HilTruth raised {type(exc).__name__}: {exc}", text) from exc
    return "rejected" if truth.errors > before else "taken"
