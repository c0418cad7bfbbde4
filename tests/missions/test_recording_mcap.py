"""``run --record FILE.mcap``: every processed frame, both calibrations and the mission log's
records in one MCAP file that Foxglove's schemas decode; a file cut short (bytes cut off, a
SIGKILLed ``run``) is recovered with all its complete chunks; write errors never stop the
mission. Short flights (the coarse approach times out after 4 s) keep these quick."""

from __future__ import annotations

import errno
import json
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
from deployment_helpers import cli, log_records, run_env
from eaglemission.missions.log import MissionLog
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mission_helpers import variant

from eaglemission.cli import main
from eaglemission.config import MissionFile, load_config
from eaglemission.flight.run import FlightOptions, fly_sync
from eaglemission.interfaces import MissionHooks
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.recording import mcap_writer as mcap_record
from eaglemission.recording.mcap_reader import Scan, recover, scan
from eaglemission.recording.mcap_writer import McapRecorder
from eaglemission.recording.options import RecordOptions


def _short(cfg: MissionFile) -> MissionFile:
    data = cfg.model_dump(mode="json")
    data["mission"]["params"]["timeouts"]["coarse_approach_s"] = 4.0
    return MissionFile.model_validate(data)


def _write(cfg: MissionFile, path: Path) -> Path:
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))
    return path


def _messages(path: Path) -> list[tuple[str, str, Any]]:
    with path.open("rb") as f:
        return [(c.topic, s.name if s else "", m) for s, c, m in
                make_reader(f).iter_messages(log_time_order=False)]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """One short simulated flight through ``eaglemission run --record x.mcap --log x.jsonl``."""
    tmp = tmp_path_factory.mktemp("mcap")
    cfg = _short(variant(load_config(check_plugins=False),
                         detector={"type": "mss", "params": {"downscale": 2}}))
    code = main(["run", str(_write(cfg, tmp / "m.yaml")), "--record", str(tmp / "x.mcap"),
                 "--log", str(tmp / "x.jsonl")])
    assert code == 3  # FAILSAFE: the coarse approach timed out, as configured
    return tmp / "x.mcap", tmp / "x.jsonl"


def test_recording_holds_every_processed_frame_calibrations_and_the_log(recorded) -> None:
    mcap, jsonl = recorded
    msgs = _messages(mcap)
    log = list(log_records(jsonl))
    frames = next(r for r in log if r["kind"] == "end")["frames"]
    for cam in (CAMERA_WIDE, CAMERA_NARROW):
        imgs = [m for t, s, m in msgs if t == f"/camera/{cam}/image"]
        assert {s for t, s, _ in msgs if t == f"/camera/{cam}/image"} == {
            "foxglove.CompressedImage"}
        assert len(imgs) == frames[cam] > 0, cam  # every processed frame, no more
        img = CompressedImage.FromString(imgs[-1].data)  # Foxglove's own schema package
        assert img.format == "jpeg" and img.frame_id == cam and img.data[:2] == b"\xff\xd8"
        assert img.timestamp.ToNanoseconds() == imgs[-1].log_time
        info = [json.loads(m.data) for t, _, m in msgs if t == f"/camera/{cam}/frame"]
        assert [i["seq"] for i in info] == [m.sequence for m in imgs]
        assert {"timestamp_ns", "host_time_ns", "exposure_s", "camera_id"} <= set(info[0])
        cal = [CameraCalibration.FromString(m.data) for t, _, m in msgs
               if t == f"/camera/{cam}/calibration"]
        assert len(cal) == 1 and cal[0].width == 1280 and cal[0].height == 960
        assert len(cal[0].K) == 9 and cal[0].K[0] > 0 and len(cal[0].P) == 12
    # the log's records are the recording's records, line for line, each on its kind's topic
    lines = [ln.strip() for ln in jsonl.read_text().splitlines() if ln.strip()]
    logged = [(t, m.data.decode()) for t, _, m in msgs if t.startswith("/log/")]
    assert sorted(d for _, d in logged) == sorted(lines)
    assert all(t == "/log/" + json.loads(d)["kind"] for t, d in logged)
    states = [json.loads(d) for t, d in logged if t == "/log/state"]
    assert states == [r for r in log if r["kind"] == "state"] and len(states) >= 3
    assert any(t == "/log/config" for t, _ in logged)
    stats = json.loads(next(m.data for t, _, m in msgs if t == "/recorder/stats"))
    assert stats["frames_dropped"] == 0 and stats["write_errors"] == 0
    # log time is the mission clock (virtual here): the log records' own t_ns
    assert all(m.log_time == json.loads(m.data)["t_ns"] for t, _, m in msgs
               if t.startswith("/log/"))


def test_a_recorded_flight_processes_the_frames_an_unrecorded_one_does(recorded) -> None:
    """Same mission file, same seed, virtual time: recording changes nothing the mission saw."""
    mcap, jsonl = recorded
    end_rec = next(r for r in log_records(jsonl) if r["kind"] == "end")
    cfg = MissionFile.model_validate(yaml.safe_load((mcap.parent / "m.yaml").read_text()))
    res = fly_sync(cfg, FlightOptions(hooks=MissionHooks(log_path=mcap.parent / "plain.jsonl")))
    end = next(r for r in log_records(mcap.parent / "plain.jsonl") if r["kind"] == "end")
    assert end["frames"] == end_rec["frames"] and sum(end["frames"].values()) >= 40
    assert end["frame_counts"] == end_rec["frame_counts"]
    assert all(n["dropped"] == 0 for n in end_rec["frame_counts"].values())
    stats = json.loads(next(m.data for t, _, m in _messages(mcap) if t == "/recorder/stats"))
    assert stats["frames_written"] == sum(end_rec["frames"].values())
    assert stats["frames_dropped"] == 0
    assert res.exit_code == 3


def test_foxglove_panels_decode_with_foxglove_schemas(recorded) -> None:
    """Detections as image annotations on their frame, saliency thumbnails, the vehicle's and
    cameras' transforms and its map position: decoded with Foxglove's schema package."""
    import cv2
    import numpy as np

    mcap, jsonl = recorded
    msgs = _messages(mcap)
    log = list(log_records(jsonl))
    for cam in (CAMERA_WIDE, CAMERA_NARROW):
        dets = [r for r in log if r["kind"] == "detection" and r["camera"] == cam]
        ann = [(m, ImageAnnotations.FromString(m.data)) for t, s, m in msgs
               if t == f"/camera/{cam}/annotations"]
        assert {s for t, s, _ in msgs if t == f"/camera/{cam}/annotations"} == {
            "foxglove.ImageAnnotations"}
        assert len(ann) == len(dets) > 0, cam  # one per processed frame: drawn or cleared
        image_stamps = {m.log_time for t, _, m in msgs if t == f"/camera/{cam}/image"}
        for (m, a), d in zip(ann, dets, strict=True):
            assert m.log_time == d["frame_t_ns"] in image_stamps  # on its very frame
            if d["corners_px"]:
                (loop,) = a.points
                assert loop.timestamp.ToNanoseconds() == d["frame_t_ns"]
                assert [(p.x, p.y) for p in loop.points] == [tuple(c) for c in d["corners_px"]]
            else:
                assert not a.points and not a.texts
        assert any(a.points for _, a in ann) or cam == CAMERA_NARROW  # wide saw the target
        sal = [CompressedImage.FromString(m.data) for t, _, m in msgs
               if t == f"/camera/{cam}/saliency"]
        # a map only where the detector ran (the keeper's tracker frames have none)
        assert len(sal) == sum(1 for d in dets if d["detector_ran"]) > 0
        thumb = cv2.imdecode(np.frombuffer(sal[-1].data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert sal[-1].format == "png" and thumb.shape == (120, 160) and thumb.max() > 0
        (mount,) = [FrameTransforms.FromString(m.data).transforms[0] for t, _, m in msgs
                    if t == f"/camera/{cam}/mount"]
        assert (mount.parent_frame_id, mount.child_frame_id) == ("base_link", cam)
        assert abs(mount.translation.x - 0.10) < 1e-9  # the config's lever arm
    states = [json.loads(m.data)["state"] for t, _, m in msgs if t == "/vehicle/state"]
    tfs = [FrameTransforms.FromString(m.data).transforms[0] for t, _, m in msgs if t == "/tf"]
    samples = {s["timestamp_ns"] for s in states}  # one transform per telemetry sample
    assert len(tfs) == len(samples) > 10
    last = tfs[-1]
    assert (last.parent_frame_id, last.child_frame_id) == ("local_ned", "base_link")
    assert [last.translation.x, last.translation.y, last.translation.z] == states[-1][
        "position_ned_m"]
    fixes = [LocationFix.FromString(m.data) for t, _, m in msgs if t == "/location"]
    assert len(fixes) == len(samples)
    assert fixes[-1].latitude == states[-1]["geodetic"]["latitude_deg"] != 0


def _chunk_ends_and_counts(path: Path) -> list[tuple[int, int]]:
    """(end offset, messages) of every chunk, in file order."""
    with path.open("rb") as f:
        idx = make_reader(f).get_summary().chunk_indexes
    with path.open("rb") as f:
        chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(idx) == len(chunks)
    return [(ci.chunk_start_offset + ci.chunk_length,
             sum(isinstance(r, Message) for r in breakup_chunk(ch)))
            for ci, ch in zip(idx, chunks)]


@pytest.mark.parametrize("fraction", [0.37, 0.81])
def test_a_file_cut_short_is_recovered_with_all_complete_chunks(recorded, tmp_path: Path,
                                                                fraction: float) -> None:
    mcap, _ = recorded
    data = mcap.read_bytes()
    cut = int(len(data) * fraction)
    (tmp_path / "cut.mcap").write_bytes(data[:cut])
    chunks = _chunk_ends_and_counts(mcap)
    expected = sum(n for end, n in chunks if end <= cut)
    assert 0 < expected < sum(n for _, n in chunks)
    p = subprocess.run(cli("log", "--recover", str(tmp_path / "cut.mcap"), "-o",
                           str(tmp_path / "ok.mcap")), capture_output=True, text=True,
                       timeout=60, env=run_env())
    assert p.returncode == 0, p.stderr
    assert f"recovered {expected} messages" in p.stdout
    assert len(_messages(tmp_path / "ok.mcap")) == expected  # a valid file: indexed reader


def test_a_sigkilled_run_is_recovered(fast_config, tmp_path: Path) -> None:
    path = _write(_short(fast_config), tmp_path / "m.yaml")
    out = tmp_path / "k.mcap"
    proc = subprocess.Popen(cli("run", str(path), "--record", str(out)),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=run_env())
    try:
        deadline = time.monotonic() + 60.0
        while True:  # kill once a few seconds of flight are on disk
            st = Scan()
            if out.exists():
                topics = {getattr(r, "topic", "") for r in scan(out, st)}
                if st.chunks >= 4 and "/camera/wide/image" in topics:
                    break
            assert proc.poll() is None and time.monotonic() < deadline, "no chunks written"
            time.sleep(0.2)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    before = Scan()
    list(scan(out, before))
    assert not before.complete
    rec = recover(out, tmp_path / "r.mcap")
    assert not rec.complete and rec.chunks >= 4 and rec.messages == before.messages
    msgs = _messages(tmp_path / "r.mcap")
    assert len(msgs) == rec.messages
    topics = {t for t, _, _ in msgs}
    assert {"/camera/wide/calibration", "/camera/narrow/calibration", "/camera/wide/image",
            "/log/state", "/log/telemetry"} <= topics


class _FullDisk:
    """A file that fails with ENOSPC once ``limit`` bytes are written."""

    def __init__(self, path: Path, limit: int) -> None:
        self._f = path.open("wb")
        self.limit = limit

    def write(self, data: bytes) -> int:
        if self._f.tell() + len(data) > self.limit:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self._f.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


def test_a_full_disk_does_not_stop_the_mission(fast_config, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(mcap_record, "open", lambda p, mode: _FullDisk(Path(p), 1_500_000),
                        raising=False)
    res = fly_sync(_short(fast_config), FlightOptions(
        record=RecordOptions(tmp_path / "full.mcap"),
        hooks=MissionHooks(log_path=tmp_path / "f.jsonl")))
    assert res.outcome is not None and res.outcome.final_state == "FAILSAFE"
    assert "timed out" in res.outcome.reason  # the configured end, not the recorder
    assert res.recording is not None and res.recording["write_errors"] == 1
    assert "No space left" in res.recording["error"] and res.recording["messages_lost"] > 0
    events = [r for r in log_records(tmp_path / "f.jsonl")
              if r["kind"] == "event" and r.get("source") == "recorder"]
    assert events and "recording stopped" in events[0]["text"]
    assert recover(tmp_path / "full.mcap", tmp_path / "back.mcap").messages > 0


def test_an_unwritable_path_is_reported_and_counted(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a folder")
    rec = McapRecorder(tmp_path / "file" / "x.mcap")
    log = MissionLog(None, now_ns=lambda: 5)
    rec.bind(log.write)
    log.subscribe(rec.record)
    log.write("state", old="A", new="B", reason="r")  # accepted, not raised
    time.sleep(0.3)
    log.write("telemetry")
    stats = rec.close()
    assert stats["write_errors"] == 1 and "cannot create" in stats["error"]
    assert stats["messages_lost"] >= 1
    assert any(r["kind"] == "event" and r["source"] == "recorder" for r in log.records)
