"""The mission log is flushed per record: a crash loses nothing already written."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from eaglemission.missions.log import MissionLog, read_log


def test_records_are_json_lines_with_times(tmp_path: Path) -> None:
    path = tmp_path / "m.jsonl"
    t = [1_000_000_000]
    with MissionLog(path, now_ns=lambda: t[0]) as log:
        log.write("state", old="A", new="B", values=np.arange(3), x=np.float32(1.5),
                  nan=float("nan"))
        t[0] += 500_000_000
        log.write("setpoint", setpoint=(1.0, 2.0))
        # readable from another handle before close: flushed already
        lines = path.read_text().splitlines()
        assert len(lines) == 2
    recs = list(read_log(path))
    assert recs[0]["kind"] == "state" and recs[0]["values"] == [0, 1, 2]
    assert recs[0]["nan"] is None and recs[1]["t_s"] == 1.5 and "wall_time" in recs[1]


def test_crash_loses_nothing(tmp_path: Path) -> None:
    path = tmp_path / "crash.jsonl"
    code = (
        "import os\n"
        "from eaglemission.missions.log import MissionLog\n"
        f"log = MissionLog({str(path)!r}, now_ns=lambda: 0)\n"
        "for i in range(100):\n"
        "    log.write('telemetry', i=i)\n"
        "os._exit(3)  # no close, no flush at exit\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], timeout=60)
    assert proc.returncode == 3
    recs = [json.loads(line) for line in path.read_text().splitlines()]
    assert [r["i"] for r in recs] == list(range(100))


def test_truncated_last_line_is_skipped(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    path.write_text('{"kind": "a"}\n{"kind": "b", "x": ')
    assert [r["kind"] for r in read_log(path)] == ["a"]
