"""``sitl-vehicle --mission -`` takes the mission's YAML on stdin: the campaign's emulator runs
write no temporary mission file, so a killed worker leaves nothing behind."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import yaml

from eaglemission.commands.run import emulator_process
from eaglemission.config import load_config


def test_the_emulator_flies_a_mission_given_on_stdin(tmp_path: Path) -> None:
    status = tmp_path / "status.json"
    doc = load_config(check_plugins=False).model_dump(mode="json")
    with emulator_process(None, str(status), mission_yaml=yaml.safe_dump(doc)) as url:
        assert url.startswith("udpin://127.0.0.1:")
        deadline = time.monotonic() + 30.0
        while not status.exists():
            assert time.monotonic() < deadline, "the emulator never reported its status"
            time.sleep(0.1)
        snap = json.loads(status.read_text())
        assert snap["armed"] is False and snap["sim_time_s"] >= 0.0


def test_a_bad_mission_on_stdin_is_named_as_stdin() -> None:
    proc = subprocess.run([sys.executable, "-m", "eaglemission.cli", "sitl-vehicle",
                           "--mission", "-", "--duration-s", "5"],
                          input="vehicle: [unclosed\n", capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "<stdin>" in proc.stderr and "Traceback" not in proc.stderr
