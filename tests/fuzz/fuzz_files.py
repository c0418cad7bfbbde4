"""Fuzz target: recording files cut short or corrupted.

* MCAP recordings into ``eaglemission log FILE`` and ``eaglemission log --recover FILE``
  (the command itself): exit 0 with its summary, or 2 with ``error: FILE: problem``; never a
  traceback.
* JSON-lines files into their readers: the mission log (:func:`read_log`) and a recorded
  run's telemetry (:func:`read_telemetry`): records, or a ``ValueError`` / ``OSError`` naming
  the file; nothing else.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import random
import time
from pathlib import Path

import numpy as np
from eaglemission.missions.log import MissionLog, read_log
from fuzz_common import FuzzCrash

from eaglemission.commands.log import COMMAND as LOG
from eaglemission.recording.folder import TELEMETRY, read_telemetry, state_to_json
from eaglemission.recording.mcap_writer import McapRecorder
from eaglemission.types import Frame, VehicleState

TARGET = "files"


def sample_recording(path: Path, *, compression: str = "zstd") -> bytes:
    """A small real recording (the flight recorder, the mission log's records, one frame),
    several chunks; its bytes."""
    rec = McapRecorder(path, chunk_s=0.0, chunk_bytes=512, compression=compression,
                       when_full="wait")
    t = [0]

    def now_ns() -> int:
        t[0] += 50_000_000
        return t[0]

    log = MissionLog(None, now_ns=now_ns)
    rec.bind(log.write)
    log.subscribe(rec.record)
    for i, (old, new) in enumerate((("IDLE", "TAKEOFF"), ("TAKEOFF", "CRUISE"),
                                    ("CRUISE", "GRASP_READY"))):
        log.write("state", old=old, new=new, reason=f"step {i}")
        log.write("telemetry", position_ned_m=(i, 0.0, -5.0), armed=True)
    rng = np.random.default_rng(0)
    rec.frame(Frame(rng.integers(0, 255, (24, 32, 3), dtype=np.uint8), t[0], "wide", 0))
    log.write("end", outcome="DONE", frame_counts={"wide": {"grabbed": 1, "processed": 1,
                                                            "skipped": 0, "dropped": 0}})
    rec.close()
    for _ in range(100):  # close() waits for the writer; the file is complete once it returns
        if path.exists():
            break
        time.sleep(0.01)
    return path.read_bytes()


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    """Cut short, bytes flipped, a block repeated, removed or swapped, or garbage."""
    k = rng.randrange(6)
    if k == 0 or not data:
        return data[: rng.randrange(len(data) + 1)]
    b = bytearray(data)
    if k == 1:
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    i, j = sorted(rng.randrange(len(b) + 1) for _ in range(2))
    if k == 2:
        return bytes(b[:j] + b[i:j] + b[j:])
    if k == 3:
        return bytes(b[:i] + b[j:])
    if k == 4:
        h = (j - i) // 2
        return bytes(b[:i] + b[i + h:j] + b[i:i + h] + b[j:])
    return bytes(rng.randrange(256) for _ in range(rng.randrange(200)))


def _log_args(path: Path, recover: bool = False, out: Path | None = None) -> argparse.Namespace:
    """The ``log`` command's own parser: the fuzz sees what a user's command line gives."""
    parser = argparse.ArgumentParser()
    LOG.add_arguments(parser)
    argv = [str(path)] + (["--recover"] if recover else []) + (
        [] if out is None else ["--output", str(out)])
    return parser.parse_args(argv)


def _run_log(path: Path, recover: bool, out: Path | None) -> str:
    stdout, stderr = io.StringIO(), io.StringIO()
    args = _log_args(path, recover, out)
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = LOG.run(args)
    except Exception as exc:
        raise FuzzCrash(TARGET, f"log{' --recover' if recover else ''} raised "
                        f"{type(exc).__name__}: {exc}", path.read_bytes()[:200]) from exc
    err = stderr.getvalue()
    if code == 0:
        return "read"
    if code != 2 or not err.startswith(f"error: {path}: ") or len(err.strip()) <= len(
            f"error: {path}:"):
        raise FuzzCrash(TARGET, f"log exited {code} with {err[:200]!r}", path.read_bytes()[:200])
    return "refused"


def check_mcap(path: Path, data: bytes) -> str:
    """``log`` and ``log --recover`` on ``data`` written to ``path``; the recovered file, when
    there is one, must itself summarise cleanly and completely."""
    path.write_bytes(data)
    first = _run_log(path, False, None)
    out = path.with_name(path.stem + ".out.mcap")
    second = _run_log(path, True, out)
    if second == "read":
        text = io.StringIO()
        with contextlib.redirect_stdout(text):
            code = LOG.run(_log_args(out))
        if code != 0 or "NO FOOTER" in text.getvalue():
            raise FuzzCrash(TARGET, "the recovered file is not a complete recording", data[:200])
    return f"{first}/{second}"


def sample_jsonl() -> tuple[bytes, bytes]:
    """A mission log and a telemetry file, as the mission and the recorder write them."""
    log = io.StringIO()
    ml = MissionLog(None, now_ns=lambda: 5)
    ml.subscribe(lambda rec, line: log.write(line if line.endswith("\n") else line + "\n"))
    ml.write("state", old="A", new="B", reason="r")
    ml.write("telemetry", position_ned_m=(1.0, 2.0, -3.0))
    states = [VehicleState(i * 1000, (float(i), 0.0, -5.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
              for i in range(3)]
    tel = "".join(state_to_json(s) + "\n" for s in states)
    return log.getvalue().encode(), tel.encode()


def check_jsonl(folder: Path, log_bytes: bytes, telemetry_bytes: bytes) -> str:
    """Both readers on the (mutated) files: records, or ValueError / OSError."""
    log_path = folder / "mission.jsonl"
    log_path.write_bytes(log_bytes)
    (folder / TELEMETRY).write_bytes(telemetry_bytes)
    outcome = []
    for name, read in (("read_log", lambda: list(read_log(log_path))),
                       ("read_telemetry", lambda: read_telemetry(folder))):
        try:
            read()
            outcome.append("read")
        except (ValueError, OSError) as exc:
            if not str(exc):
                raise FuzzCrash(TARGET, f"{name}: {type(exc).__name__} without a message",
                                (log_bytes[:200], telemetry_bytes[:200])) from exc
            outcome.append("refused")
        except Exception as exc:
            raise FuzzCrash(TARGET, f"{name} raised {type(exc).__name__}: {exc}",
                            (log_bytes[:200], telemetry_bytes[:200])) from exc
    return "/".join(outcome)
