"""The mission log: one JSON object per line, flushed (and optionally fsync'ed) per record.

Every record has ``kind``, ``t_s`` (mission clock, seconds; virtual in simulation),
``t_ns`` (host monotonic / virtual nanoseconds, docs/conventions.md) and ``wall_time`` (UTC,
ISO 8601). Kinds: ``start``, ``config`` (the mission file, its SHA-256, package versions),
``state`` (state changes with reason), ``detection``, ``estimate``, ``filter``, ``setpoint``
(requested and ``sent``: what the safety envelope passed on; ``latency_ms`` when it follows a
fresh estimate), ``telemetry``, ``command``, ``event`` (vehicle / safety events: clamps and
refusals; the recorder's problems), ``failsafe_params``, ``param_set``, ``end``,
``fault_injected`` (the ``faults:`` section's injector: kind, where, size) and
``fault_detected`` (the mission noticed something wrong: ``what``, ``text``, ``response``; a slow
frame is judged on host wall time and carries ``wall_clock: true``: not part of a seed's
deterministic log).
A crash loses nothing already written: each line is complete and flushed before ``write``
returns. Subscribers (:meth:`MissionLog.subscribe`: the MCAP recorder) get every record and
its exact line: the JSON-lines file and the recording hold the same records.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import enum
import json
import math
import os
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np


def to_jsonable(value: Any) -> Any:
    """Numbers, strings, lists and dicts for ``json.dumps`` (numpy, enums, dataclasses)."""
    if value is None or isinstance(value, bool | str | int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, enum.Enum):
        return value.value if isinstance(value.value, str | int) else value.name
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, np.ndarray):
        return [to_jsonable(v) for v in value.tolist()]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [to_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return repr(value)


class MissionLog:
    """Append JSON lines to ``path`` (or to an open text stream).

    Parameters
    ----------
    path : file to create or overwrite (parent folders are created), or None to keep records only in memory
    now_ns : the mission clock
    fsync : also ``os.fsync`` each record (survives a power cut, slower)
    keep : keep the records in memory too (``records``), for summaries and tests
    """

    def __init__(self, path: str | Path | None, *, now_ns: Callable[[], int],
                 fsync: bool = False, keep: bool = True) -> None:
        self.path = Path(path) if path is not None else None
        self._now_ns = now_ns
        self._fsync = fsync
        self._keep = keep
        self.records: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._fh: IO[str] | None = None
        self._sinks: list[Callable[[dict[str, Any], str], None]] = []
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "w", encoding="utf-8")  # noqa: SIM115 - closed in close()

    def write(self, kind: str, **fields: Any) -> dict[str, Any]:
        t_ns = int(self._now_ns())
        record = {"kind": kind, "t_s": round(t_ns * 1e-9, 6), "t_ns": t_ns,
                  "wall_time": _dt.datetime.now(_dt.UTC).isoformat(timespec="microseconds")}
        record.update({k: to_jsonable(v) for k, v in fields.items()})
        line = json.dumps(record, separators=(",", ":"), allow_nan=False)
        with self._lock:
            if self._keep:
                self.records.append(record)
            if self._fh is not None:
                self._fh.write(line + "\n")
                self._fh.flush()
                if self._fsync:
                    os.fsync(self._fh.fileno())
        for sink in self._sinks:  # outside the lock: a sink may write a record itself
            sink(record, line)
        return record

    def subscribe(self, sink: Callable[[dict[str, Any], str], None]) -> None:
        """Call ``sink(record, line)`` with every record from now on and the JSON line the
        file gets (a flight recording: the log's records are its records)."""
        self._sinks.append(sink)

    def of_kind(self, kind: str) -> list[dict[str, Any]]:
        return [r for r in self.records if r["kind"] == kind]

    def close(self) -> None:
        with self._lock:
            if self._fh is not None:
                self._fh.close()
                self._fh = None

    def __enter__(self) -> MissionLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_log(path: str | Path) -> Iterator[dict[str, Any]]:
    """Records of a mission log; a truncated last line (crash mid-write) is skipped."""
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            line = line.strip()
            if not line:
                continue
            try:
                yield json.loads(line)
            except json.JSONDecodeError:
                return
