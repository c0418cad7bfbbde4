"""``eaglemission replay``: the replay's mission file and the comparison of a replay's mission
log with the recording's (docs/recording.md, "Replaying a recording").

Compared channels, each in log order:

* ``setpoint``: every commanded setpoint: its time, the state, what the mission asked
  (``setpoint``, ``goal``, ``target``) and what the safety envelope sent (``sent``);
* ``verdict``: the envelope's interventions (clamps, refusals) and refused setpoints;
* ``state``: every state change with its time and reason.

"Identical" means every record of every channel is equal, field for field, floats bit for bit
(the times are the mission clock's nanoseconds). Everything else a log holds (latencies, wall
times, the frames' own records) is not compared.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE

CHANNELS = ("setpoint", "verdict", "state")
_FIELDS = {"setpoint": ("t_ns", "state", "setpoint", "sent", "goal", "target"),
           "state": ("t_ns", "old", "new", "reason", "action")}


def replay_config_data(config: Mapping[str, Any], path: Path) -> dict[str, Any]:
    """A mission file (as JSON values) flying its detector, estimators and mission on the
    recording at ``path``: both cameras and the vehicle become ``replay`` plugins reading it
    (``pacing: clock``), nothing is simulated (no world) and nothing is recorded."""
    data: dict[str, Any] = json.loads(json.dumps(dict(config)))
    data["vehicle"] = {"type": "replay", "params": {"path": str(path)}}
    for cid in (CAMERA_WIDE, CAMERA_NARROW):
        cam = dict(data["cameras"][cid])
        cam["type"] = "replay"
        cam["params"] = {"path": str(path), "camera": cid, "pacing": "clock"}
        data["cameras"][cid] = cam
    data["world"] = None
    data["recording"] = None
    return data


def _jsonable(value: Any) -> Any:
    return json.loads(json.dumps(value))


def channels(records: Iterable[Mapping[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """The compared records of a mission log, per channel (JSON values)."""
    out: dict[str, list[dict[str, Any]]] = {c: [] for c in CHANNELS}
    for r in records:
        kind = r.get("kind")
        if kind in _FIELDS:
            out[str(kind)].append(_jsonable({k: r.get(k) for k in _FIELDS[str(kind)]}))
        elif kind == "event" and (r.get("event_kind") == "safety"
                                  or r.get("source") == "setpoint"):
            out["verdict"].append(_jsonable({"t_ns": r.get("t_ns"), "text": r.get("text"),
                                             "data": r.get("data")}))
    return out


@dataclass
class Divergence:
    channel: str
    index: int
    t_ns: int
    t0_ns: int
    recorded: dict[str, Any] | None
    replayed: dict[str, Any] | None

    @property
    def t_s(self) -> float:
        """Mission time (since the recorded ``start`` record)."""
        return (self.t_ns - self.t0_ns) * 1e-9

    def lines(self) -> list[str]:
        return [f"first divergence at t = {self.t_s:.3f} s on {self.channel} #{self.index}:",
                f"  recorded: {_short(self.recorded)}",
                f"  replayed: {_short(self.replayed)}"]


def _short(rec: dict[str, Any] | None) -> str:
    if rec is None:
        return "(none: the other side has more)"
    text = json.dumps(rec, separators=(",", ":"))
    return text if len(text) <= 400 else text[:397] + "..."


@dataclass
class Comparison:
    recorded: dict[str, list[dict[str, Any]]]
    replayed: dict[str, list[dict[str, Any]]]
    divergence: Divergence | None = None
    t0_ns: int = 0
    detections: dict[str, tuple[int, int]] = field(default_factory=dict)
    """Camera -> (recorded, replayed) frames with a detection."""

    @property
    def identical(self) -> bool:
        return self.divergence is None

    def headline(self) -> str:
        n_sp = len(self.recorded["setpoint"])
        n_st = len(self.recorded["state"])
        if self.identical:
            return f"identical: {n_sp} setpoints, {n_st} state changes"
        return (f"diverged: recorded {n_sp} setpoints, {n_st} state changes; replayed "
                f"{len(self.replayed['setpoint'])} setpoints, "
                f"{len(self.replayed['state'])} state changes")

    def side_by_side(self) -> list[str]:
        """States and times, detections per camera, setpoint counts: recorded | replayed."""
        def states(recs: list[dict[str, Any]]) -> list[str]:
            return [f"{(r['t_ns'] - self.t0_ns) * 1e-9:7.2f} s {r['new']}" for r in recs]

        a, b = states(self.recorded["state"]), states(self.replayed["state"])
        out = [f"  {'recorded':<36} | replayed"]
        for i in range(max(len(a), len(b))):
            out.append(f"  {a[i] if i < len(a) else '':<36} | {b[i] if i < len(b) else ''}")
        for cam, (x, y) in sorted(self.detections.items()):
            out.append(f"  {'detections ' + cam + ': ' + str(x):<36} | {y}")
        out.append(f"  {'setpoints: ' + str(len(self.recorded['setpoint'])):<36} | "
                   f"{len(self.replayed['setpoint'])}")
        out.append(f"  {'envelope verdicts: ' + str(len(self.recorded['verdict'])):<36} | "
                   f"{len(self.replayed['verdict'])}")
        return out


def detections(records: Iterable[Mapping[str, Any]]) -> Counter[str]:
    return Counter(str(r.get("camera")) for r in records
                   if r.get("kind") == "detection" and r.get("used"))


def compare(recorded: Sequence[Mapping[str, Any]], replayed: Sequence[Mapping[str, Any]]
            ) -> Comparison:
    """Channel by channel; the divergence reported is the earliest in time."""
    a, b = channels(recorded), channels(replayed)
    t0 = next((int(r["t_ns"]) for r in recorded if r.get("kind") == "start"), 0)
    cmp = Comparison(a, b, t0_ns=t0)
    da, db = detections(recorded), detections(replayed)
    cmp.detections = {c: (da.get(c, 0), db.get(c, 0)) for c in sorted(set(da) | set(db))}
    first: Divergence | None = None
    for ch in CHANNELS:
        xs, ys = a[ch], b[ch]
        for i in range(max(len(xs), len(ys))):
            x = xs[i] if i < len(xs) else None
            y = ys[i] if i < len(ys) else None
            if x == y:
                continue
            t = min(int(r["t_ns"]) for r in (x, y) if r is not None)
            if first is None or t < first.t_ns:
                first = Divergence(ch, i, t, t0, x, y)
            break
    cmp.divergence = first
    return cmp
