"""Import PX4's parameter set (names, types, values) as data for the MAVLink emulator.

    # a fresh PX4 v1.16 SITL, SIH quad (sihsim_quadx), whose API link sends to 14541 (instance 1)
    python benchmarks/px4_params_import.py --url udpin:0.0.0.0:14541 \\
        --metadata PX4-Autopilot/build/px4_sitl_default/parameters.json \\
        --out drivers/vehicles/px4_params_v1_16_sihsim_quadx.json

Asks the running autopilot for its whole list (PARAM_REQUEST_LIST, then PARAM_REQUEST_READ by
index for anything missed), in PX4's own order (its ``param_index``), and checks every name
and type against PX4's parameter metadata of the same build (``parameters.json``: the build's
every parameter with its default; the running list has only the ~900 the airframe uses, with
the airframe's values, e.g. RTL_RETURN_ALT 30 where the metadata default is 60). Only facts
are written: name, MAVLink type, the value the running autopilot reported, and the metadata
default. ``MAV_SYS_ID`` is written as 1 (the instance's own id is the emulator's ``sysid``).
Start a fresh autopilot first: a parameter changed since boot would be imported changed.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import sys
import time
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

TYPES = {6: "INT32", 9: "REAL32"}


def fetch(url: str, timeout_s: float) -> tuple[list[tuple[int, str, int, float]], int, str]:
    """(index, name, MAVLink type, value) of every parameter, the count and the version."""
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(url, source_system=245, source_component=190,
                                   dialect="development")
    hb = m.wait_heartbeat(timeout=timeout_s)
    if hb is None:
        raise SystemExit(f"no HEARTBEAT on {url} within {timeout_s:g} s")
    sysid = hb.get_srcSystem()
    m.mav.heartbeat_send(6, 8, 0, 0, 0)
    m.mav.command_long_send(sysid, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0)  # AUTOPILOT_VERSION
    version = "?"
    got: dict[int, tuple[str, int, float]] = {}
    count = -1
    m.mav.param_request_list_send(sysid, 1)
    deadline = time.monotonic() + timeout_s
    last_new = time.monotonic()
    while time.monotonic() < deadline:
        msg = m.recv_match(type=["PARAM_VALUE", "AUTOPILOT_VERSION"], blocking=True, timeout=0.2)
        if msg is not None and msg.get_type() == "AUTOPILOT_VERSION":
            v = msg.flight_sw_version
            version = f"{v >> 24 & 0xFF}.{v >> 16 & 0xFF}.{v >> 8 & 0xFF} (type {v & 0xFF}), " \
                      f"custom {bytes(msg.flight_custom_version).hex()}"
            continue
        if msg is not None:
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            name = name.rstrip("\x00")
            if name == "_HASH_CHECK" or msg.param_index == 65535:
                continue
            count = msg.param_count
            if msg.param_index not in got:
                last_new = time.monotonic()
            got[msg.param_index] = (name, msg.param_type, float(msg.param_value))
        if count > 0 and len(got) >= count:
            break
        if count > 0 and time.monotonic() - last_new > 1.0:  # ask again for the ones missed
            for i in range(count):
                if i not in got:
                    m.mav.param_request_read_send(sysid, 1, b"", i)
            last_new = time.monotonic()
    if count < 0 or len(got) < count:
        raise SystemExit(f"got {len(got)} of {count} parameters within {timeout_s:g} s")
    out = []
    for i in sorted(got):
        name, ptype, raw = got[i]
        value = struct.unpack("<i", struct.pack("<f", raw))[0] if ptype == 6 else raw
        out.append((i, name, ptype, value))
    return out, count, version


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", default="udpin:0.0.0.0:14541", help="pymavlink URL of the autopilot")
    ap.add_argument("--metadata", required=True, help="the build's parameters.json")
    ap.add_argument("--out", required=True)
    ap.add_argument("--airframe", default="sihsim_quadx (SYS_AUTOSTART 10040)")
    ap.add_argument("--timeout-s", type=float, default=60.0)
    args = ap.parse_args(argv)
    with open(args.metadata, encoding="utf-8") as f:
        meta = {p["name"]: p for p in json.load(f)["parameters"]}
    params, count, version = fetch(args.url, args.timeout_s)
    rows: list[list[Any]] = []
    problems = []
    for _, name, ptype, value in params:
        md = meta.get(name)
        if md is None:
            problems.append(f"{name}: not in the metadata")
            default: Any = None
        else:
            default = md.get("default")
            want = {"Int32": 6, "Float": 9}.get(md.get("type", ""))
            if want is not None and want != ptype:
                problems.append(f"{name}: type {ptype} on the wire, {md.get('type')} in the metadata")
        if name == "MAV_SYS_ID":
            value = 1
        if ptype not in TYPES:
            problems.append(f"{name}: MAVLink type {ptype} not imported")
            continue
        rows.append([name, TYPES[ptype], value if ptype == 6 else round(value, 7), default])
    doc = {
        "source": f"PX4 v1.16 SITL, airframe {args.airframe}: its PARAM_REQUEST_LIST answer "
                  "(names, types, values in its order) checked against the build's "
                  "parameters.json (defaults); generated by benchmarks/px4_params_import.py",
        "autopilot_version": version,
        "param_count": count,
        "columns": ["name", "type", "value", "metadata_default"],
        "params": rows,
    }
    with open(args.out, "w", encoding="utf-8") as f:  # one parameter a line: readable diffs
        head = json.dumps({k: v for k, v in doc.items() if k != "params"}, indent=1)
        f.write(head[:-2] + ',\n "params": [\n')
        f.write(",\n".join("  " + json.dumps(r) for r in rows))
        f.write("\n ]\n}\n")
    print(f"{len(rows)} of {count} parameters written to {args.out} (autopilot {version})")
    for p in problems:
        print("  " + p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
