"""Helpers of the deployment tests: real processes (``eaglemission run``, ``eaglemission
sitl-vehicle``), free ports, mission-file variants written to disk. Not a test module."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[2]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def mission_file(tmp: Path, name: str, base: str = "sitl_synthetic.yaml", **sections: Any) -> Path:
    """A shipped config (``base``) with some sections' keys replaced, written to disk."""
    data = yaml.safe_load((REPO / "configs" / base).read_text())
    image = (data.get("target") or {}).get("appearance_image")
    if image and not Path(image).is_absolute():  # relative to the shipped file, not the copy
        data["target"]["appearance_image"] = str(REPO / "configs" / image)
    for key, value in sections.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict) and not value.get("_replace"):
            data[key] = {**data[key], **value}
        else:
            data[key] = {k: v for k, v in value.items() if k != "_replace"} \
                if isinstance(value, dict) else value
    path = tmp / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "eaglemission.cli", *args]


@contextmanager
def sitl_vehicle(mission: Path, port: int, status: Path) -> Iterator[subprocess.Popen[bytes]]:
    """``eaglemission sitl-vehicle`` as its own process, sending to ``port``; stopped with
    SIGTERM at the end."""
    proc = subprocess.Popen(cli("sitl-vehicle", "--mission", str(mission), "--mavlink",
                                f"udpout://127.0.0.1:{port}", "--status-json", str(status)),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 20.0
        while not status.exists():  # it writes its first status once running
            if proc.poll() is not None or time.monotonic() > deadline:
                err = proc.stderr.read().decode() if proc.stderr else ""
                raise AssertionError(f"sitl-vehicle did not start: {err}")
            time.sleep(0.1)
        yield proc
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)
        if proc.stderr is not None:
            proc.stderr.close()


def read_status(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


def log_records(path: Path) -> list[dict[str, Any]]:
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            break
    return out


def run_env() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("MPLBACKEND", "Agg")
    return env
