"""``run --live HOST:PORT``: a simulated flight served over the Foxglove WebSocket protocol to
real clients (a minimal protocol client, ``foxglove_ws``): the recording's channels are
advertised, messages arrive and decode with Foxglove's schemas (the package's and the
advertised FileDescriptorSet), thumbnails and telemetry are throttled on mission time, the log
channels carry the very lines of the ``--log`` file, and a stalled client, a client that
leaves, or a port in use never stalls or crashes a flight (the last refuses it: exit 5)."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_ws import FoxgloveClient, decode_schema
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from eaglemission.cli import main
from eaglemission.config import MissionFile, load_config
from eaglemission.recording.live import LiveOptions, options_from_config, parse_listen

pytest.importorskip("foxglove", reason="foxglove-sdk (pip install eaglemission[live])")

CAMS = ("wide", "narrow")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _short_config(tmp: Path) -> Path:
    """The embedded mission, fast detector, coarse approach timing out after 4 s (FAILSAFE)."""
    data = load_config(check_plugins=False).model_dump(mode="json")
    data["detector"] = {"type": "mss", "params": {"downscale": 2}}
    data["mission"]["params"]["timeouts"]["coarse_approach_s"] = 4.0
    path = tmp / "m.yaml"
    path.write_text(yaml.safe_dump(MissionFile.model_validate(data).model_dump(mode="json"),
                                   sort_keys=False))
    return path


def _stalled(port: int, out: dict[str, Any]) -> None:
    """Subscribe to everything, then never read again (a tiny TCP window: a dead radio link)."""
    c = FoxgloveClient("127.0.0.1", port, timeout_s=20.0, rcvbuf_bytes=2048)
    while len(c.received.channels) < 10:
        c.handle(*c.recv())
    out["stalled"] = c  # closed by the test, after the flight


def _leaver(port: int, out: dict[str, Any]) -> None:
    """Subscribe, read the first data message, disconnect."""
    c = FoxgloveClient("127.0.0.1", port, timeout_s=20.0)
    while not c.received.messages:
        c.handle(*c.recv())
    c.close()
    out["leaver"] = True


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, ...]:
    """One short flight with ``--live``, ``--log`` and ``--record``, watched by three clients;
    returns what the reading client received, the log's records and lines, the exit code and
    the recording's ``(image topic, seq)`` pairs."""
    tmp = tmp_path_factory.mktemp("live")
    port = _free_port()
    out: dict[str, Any] = {}
    reader = FoxgloveClient.__new__(FoxgloveClient)  # connected in its thread

    def read() -> None:
        FoxgloveClient.__init__(reader, "127.0.0.1", port, timeout_s=20.0)
        out["received"] = reader.read_all(until_closed_s=90.0)

    threads = [threading.Thread(target=read, daemon=True),
               threading.Thread(target=_stalled, args=(port, out), daemon=True),
               threading.Thread(target=_leaver, args=(port, out), daemon=True)]
    for t in threads:
        t.start()
    code = main(["run", str(_short_config(tmp)), "--live", f"127.0.0.1:{port}",
                 "--log", str(tmp / "x.jsonl"), "--record", str(tmp / "x.mcap")])
    for t in threads:
        t.join(timeout=30.0)
    assert not any(t.is_alive() for t in threads)
    out["stalled"].close()
    assert out.get("leaver")
    lines = (tmp / "x.jsonl").read_text().splitlines()
    with (tmp / "x.mcap").open("rb") as f:
        recorded = {(c.topic, m.sequence) for _, c, m in make_reader(f).iter_messages()
                    if c.topic.endswith("/image")}
    return out["received"], [json.loads(ln) for ln in lines], lines, code, recorded


def test_live_flight_advertises_the_recordings_channels_and_they_decode(served) -> None:
    rx, records, _, code, recorded = served
    assert code == 3  # FAILSAFE: the coarse approach timed out, as configured: the flight ended
    assert rx.server_info.get("name") == "eaglemission"
    by_topic = {ch["topic"]: ch for ch in rx.channels.values()}
    for cam in CAMS:
        assert by_topic[f"/camera/{cam}/image"]["schemaName"] == "foxglove.CompressedImage"
        assert by_topic[f"/camera/{cam}/calibration"]["schemaName"] == (
            "foxglove.CameraCalibration")
    for kind in ("state", "telemetry", "setpoint", "detection", "end"):
        assert by_topic[f"/log/{kind}"]["encoding"] == "json"
    # the advertised schema is Foxglove's: build the class from its FileDescriptorSet
    fds = descriptor_pb2.FileDescriptorSet.FromString(
        decode_schema(by_topic["/camera/wide/image"]))
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    Advertised = message_factory.GetMessageClass(
        pool.FindMessageTypeByName("foxglove.CompressedImage"))
    processed = next(r for r in records if r["kind"] == "end")["frames"]
    for cam in CAMS:
        imgs = rx.messages.get(f"/camera/{cam}/image", [])
        assert 0 < len(imgs) <= processed[cam], cam
        log_ns, payload = imgs[-1]
        img = CompressedImage.FromString(payload)  # Foxglove's own schema package
        assert img.format == "jpeg" and img.frame_id == cam
        assert img.timestamp.ToNanoseconds() == log_ns
        assert Advertised.FromString(payload).data == img.data
        thumb = cv2.imdecode(np.frombuffer(img.data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert thumb.shape[1] == 320 and thumb.shape[0] == 240  # 1280x960 -> 320 px wide
        stamps = [t for t, _ in imgs]
        assert all(b - a >= 500_000_000 for a, b in zip(stamps, stamps[1:])), "2 Hz at most"
        cal = CameraCalibration.FromString(rx.messages[f"/camera/{cam}/calibration"][0][1])
        assert (cal.width, cal.height) == (320, 240) and cal.K[0] > 0
        info = [json.loads(p) for _, p in rx.messages[f"/camera/{cam}/frame"]]
        assert {i["thumbnail_width_px"] for i in info} == {320}
        # the recorder got every processed frame, the live view a throttled part of the same
        topic = f"/camera/{cam}/image"
        assert len({s for t, s in recorded if t == topic}) == processed[cam]
        assert {(topic, i["seq"]) for i in info} <= recorded


def test_live_log_channels_carry_the_log_files_lines_throttled(served) -> None:
    rx, records, lines, _, _ = served
    got = {topic: [p.decode() for _, p in msgs] for topic, msgs in rx.messages.items()
           if topic.startswith("/log/")}
    state_lines = [ln for ln, r in zip(lines, records) if r["kind"] == "state"]
    assert got["/log/state"] and set(got["/log/state"]) <= set(state_lines)
    assert got["/log/state"][-1] == state_lines[-1]  # followed to the final state
    assert got["/log/end"] == [ln for ln, r in zip(lines, records) if r["kind"] == "end"]
    detections = [ln for ln, r in zip(lines, records) if r["kind"] == "detection"]
    assert got["/log/detection"] and set(got["/log/detection"]) <= set(detections)
    for kind in ("telemetry", "setpoint"):
        sent = [json.loads(p) for p in got[f"/log/{kind}"]]
        assert sent and {json.dumps(r, separators=(",", ":")) for r in sent} <= set(lines)
        t = [r["t_ns"] for r in sent]
        assert all(b - a >= 100_000_000 for a, b in zip(t, t[1:])), f"{kind}: 10 Hz at most"


def test_port_in_use_refuses_the_flight_before_take_off(tmp_path: Path, capsys) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["run", str(_short_config(tmp_path)), "--live", f"127.0.0.1:{port}",
                     "--log", str(tmp_path / "x.jsonl")])
    err = capsys.readouterr().err
    assert code == 5, err  # preflight refused
    assert f"ws://127.0.0.1:{port}" in err and "in use" in err
    assert not (tmp_path / "x.jsonl").exists()  # no mission started: nothing armed


@pytest.mark.parametrize(("text", "expected"), [
    ("127.0.0.1:9000", ("127.0.0.1", 9000)), (":9001", ("127.0.0.1", 9001)),
    ("0.0.0.0:8765", ("0.0.0.0", 8765)), ("[::1]:9002", ("::1", 9002)),
    ("localhost", ("localhost", 8765))])
def test_parse_listen(text: str, expected: tuple[str, int]) -> None:
    assert parse_listen(text) == expected


@pytest.mark.parametrize("bad", ["host:port", "a:b:c", "1.2.3.4:70000", "[::1", ""])
def test_parse_listen_refuses_with_the_option_named(bad: str) -> None:
    with pytest.raises(ValueError, match="--live"):
        parse_listen(bad)


def test_live_options_from_the_config_section_and_the_cli() -> None:
    data = load_config(check_plugins=False).model_dump(mode="json")
    data["live"] = {"listen": "0.0.0.0:9100", "image_hz": 1.0, "image_width_px": 160}
    cfg = MissionFile.model_validate(data)
    opt = options_from_config(cfg.live)
    assert (opt.host, opt.port, opt.image_hz, opt.image_width_px) == ("0.0.0.0", 9100, 1.0, 160)
    assert options_from_config(cfg.live, "127.0.0.1:9200").port == 9200
    assert options_from_config(None) == LiveOptions()
    data["live"] = {"listen": "nohost:x"}
    with pytest.raises(ValueError, match="listen"):
        MissionFile.model_validate(data)


def test_bad_live_argument_is_a_config_error(tmp_path: Path, capsys) -> None:
    cfg = _short_config(tmp_path)
    assert main(["run", "--live", str(cfg)]) == 2  # the mission file taken as HOST:PORT
    assert "not HOST:PORT" in capsys.readouterr().err


def test_throttle_on_mission_time_and_counts() -> None:
    """50 Hz telemetry and 25 Hz frames for 2 s of mission time: 10 Hz and 2 Hz go out."""
    from eaglemission.recording.live import LiveSink
    from eaglemission.types import Frame

    sink = LiveSink(LiveOptions(port=0))
    client = FoxgloveClient("127.0.0.1", sink.port)
    while not client.received.channels:
        client.handle(*client.recv())
    img = np.zeros((480, 640, 3), np.uint8)
    for i in range(100):
        t_ns = 1_000_000_000 + i * 20_000_000
        sink.record({"kind": "telemetry", "t_ns": t_ns}, json.dumps({"kind": "telemetry",
                                                                    "t_ns": t_ns}))
        if i % 2 == 0:
            sink.frame(Frame(img, t_ns, "wide", i // 2))
    stats = sink.close()
    client.close()
    assert stats["records"] == 20 and stats["images"] == 4 and stats["throttled"] == 80 + 46
    assert stats["dropped"] == 0 and stats["errors"] == 0


def test_a_stalled_client_never_blocks_the_sink_nor_the_other_clients() -> None:
    """~19 MB to a client that stopped reading behind a 2 kB TCP window (far beyond the
    kernel's buffers and the server's 16-message backlog): every record is still published
    at once, and a reading client gets them to the last one."""
    from eaglemission.recording.live import LiveSink

    sink = LiveSink(LiveOptions(port=0, backlog_messages=16, queue_items=1000))
    out: dict[str, Any] = {}
    _stalled(sink.port, out)
    reader = FoxgloveClient("127.0.0.1", sink.port)
    thread = threading.Thread(target=lambda: out.update(rx=reader.read_all(until_closed_s=60)),
                              daemon=True)
    thread.start()
    for i in range(200):  # until the reader is subscribed
        sink.record({"kind": "state", "t_ns": i}, json.dumps({"kind": "state", "i": i}))
        if reader.received.messages.get("/log/state"):
            break
        threading.Event().wait(0.05)
    assert reader.received.messages.get("/log/state"), "the reader never got subscribed"
    pad = "x" * 64_000
    n = 300
    for i in range(n):
        sink.record({"kind": "event", "t_ns": i}, json.dumps({"kind": "event", "i": i,
                                                              "pad": pad}))
    deadline = time.monotonic() + 60.0  # the reading client follows at its own pace
    while time.monotonic() < deadline:
        got_now = reader.received.messages.get("/log/event", [])
        if got_now and json.loads(got_now[-1][1])["i"] == n - 1:
            break
        threading.Event().wait(0.05)
    stats = sink.close(timeout_s=2.0)  # the server's stop() would wait for the stalled one
    stalled: FoxgloveClient = out["stalled"]
    stalled.close()
    thread.join(timeout=30.0)
    assert stats["dropped"] == 0 and stats["errors"] == 0
    assert stats["records"] >= n  # the sink's thread published every one: never blocked
    got = [json.loads(p)["i"] for _, p in out["rx"].messages.get("/log/event", [])]
    assert got and got[-1] == n - 1  # the reading client followed to the last one
    assert "stalled client" in stats["error"]  # close() did not wait for it


def test_a_client_subscribing_late_gets_the_calibration_at_once() -> None:
    """The calibration was published before the client connected; the periodic repeat is an
    hour away: the subscription itself brings it (a CI run lost the race without this)."""
    from eaglemission.geometry import CameraModel
    from eaglemission.recording.live import LiveSink

    sink = LiveSink(LiveOptions(port=0, repeat_s=3600.0))
    sink.calibration("wide", CameraModel.from_lens("wide", focal_length_mm=2.8,
                                                   resolution_px=(1280, 960)), 5)
    deadline = time.monotonic() + 10.0
    while sink.stats["messages"] < 2 and time.monotonic() < deadline:  # published, to nobody
        threading.Event().wait(0.02)
    assert sink.stats["messages"] == 2
    client = FoxgloveClient("127.0.0.1", sink.port, timeout_s=5.0)
    deadline = time.monotonic() + 10.0
    while "/camera/wide/calibration" not in client.received.messages:
        assert time.monotonic() < deadline, "no calibration for the late subscriber"
        try:
            client.handle(*client.recv())
        except TimeoutError:
            continue
    sink.close()
    client.close()
    cal = CameraCalibration.FromString(client.received.messages["/camera/wide/calibration"][0][1])
    assert cal.frame_id == "wide" and cal.width == 320
