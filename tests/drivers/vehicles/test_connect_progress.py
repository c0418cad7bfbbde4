"""Connecting to an autopilot that does not answer: the flight says where it waits, every few
seconds, then why it gave up and the fix (one line, exit 4). MAVSDK over a UDP port nobody
sends to."""

from __future__ import annotations

import socket

import pytest

from eaglemission.config import MissionFile, load_config
from eaglemission.flight.run import EXIT_CONNECTION, FlightOptions, fly_sync

pytestmark = pytest.mark.machine  # a UDP port of this machine (tests/conftest.py)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_an_unreachable_autopilot_is_waited_for_aloud() -> None:
    pytest.importorskip("mavsdk")
    url = f"udpin://127.0.0.1:{_free_udp_port()}"
    data = load_config(check_plugins=False).model_dump()
    data["vehicle"] = {"type": "mavsdk", "params": {"url": url, "connect_timeout_s": 2.5}}
    lines: list[str] = []
    res = fly_sync(MissionFile.model_validate(data),
                   FlightOptions(on_line=lines.append, progress_every_s=0.7))
    assert res.exit_code == EXIT_CONNECTION and res.outcome is None
    assert lines[0] == f"connecting to the autopilot on {url}"
    waits = [line for line in lines if line.startswith("waiting for the autopilot on ")]
    assert len(waits) >= 2, lines
    assert waits[0] == f"waiting for the autopilot on {url} ... 1 s"
    assert res.error.startswith(f"vehicle: no autopilot heard on {url} within 2.5 s: check "
                                "the URL"), res.error
    assert "\n" not in res.error
