"""Helpers of the deployment tests: real processes (``eaglemission run``, ``eaglemission
sitl-vehicle``), free ports, mission-file variants written to disk, the field config on the
genicam wheel's GenTL test producer. Not a test module."""

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

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]


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


def write_calibration(path: Path, w: int, h: int, fx: float) -> Path:
    """A distortion-free ROS camera_info calibration of a ``w`` x ``h`` px camera."""
    path.write_text(yaml.safe_dump({
        "image_width": w, "image_height": h, "camera_name": path.stem,
        "camera_matrix": {"rows": 3, "cols": 3,
                          "data": [fx, 0.0, (w - 1) / 2, 0.0, fx, (h - 1) / 2, 0.0, 0.0, 1.0]},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5}}))
    return path


def viky_cti() -> str:
    """The genicam wheel's GenTL test producer (the test is skipped without it)."""
    genicam = pytest.importorskip("genicam")
    cti = os.path.join(os.path.dirname(genicam.__file__), "viky.cti")
    if not os.path.isfile(cti):
        pytest.skip("the genicam wheel ships no viky.cti")
    return cti


VIKY_SIZE_PX = (800, 600)


def viky_field_config(tmp: Path, port: int) -> dict[str, Any]:
    """configs/field_basler_px4.yaml with the vehicle on ``udpin://127.0.0.1:<port>`` and both
    cameras on the viky producer's devices (green: wide, blue: narrow; RGBa8 at 800x600 px,
    calibrations written to ``tmp``)."""
    cti = viky_cti()
    data: dict[str, Any] = yaml.safe_load((REPO / "configs" / "field_basler_px4.yaml").read_text())
    data["vehicle"]["params"] = {"url": f"udpin://127.0.0.1:{port}", "connect_timeout_s": 20}
    data["target"]["appearance_image"] = str(REPO / "configs" / data["target"]["appearance_image"])
    w, h = VIKY_SIZE_PX
    for cid, dev, fx in (("wide", "VikyTL_DEV_green", 747.0), ("narrow", "VikyTL_DEV_blue",
                                                                 3200.0)):
        cam = data["cameras"][cid]
        cam["params"] = {"cti_files": [cti], "device_id": dev, "pixel_format": "RGBa8",
                         "frame_rate_hz": 30}
        cam["calibration_file"] = str(write_calibration(tmp / f"{cid}.yaml", w, h, fx))
    return data
