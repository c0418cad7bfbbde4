"""Replay driver, recorder round trip, and the faults of file sources."""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest
from eaglemission.drivers.cameras.replay.camera import ReplayCamera

from eaglemission import registry
from eaglemission.errors import CameraError, EndOfStream, FrameError, GrabTimeout
from eaglemission.geometry import CameraModel
from eaglemission.recording.folder import (
    RunRecorder,
    read_camera_model,
    read_telemetry,
    telemetry_history,
)
from eaglemission.types import FlightMode, Frame, GeoPoint, VehicleState


def _model(w: int, h: int, cid: str = "wide") -> CameraModel:
    return CameraModel.from_lens(cid, focal_length_mm=2.8, resolution_px=(w, h))


def _drain(cam: ReplayCamera) -> list[Frame]:
    out = []
    while True:
        try:
            out.append(cam.grab(timeout_s=1.0))
        except EndOfStream:
            return out


def test_replay_is_a_registered_camera_plugin():
    assert registry.get("cameras", "replay") is ReplayCamera


def test_davis_sequences_yield_every_frame_in_order(davis):
    seqs = sorted(p for p in davis.iterdir() if (p / "frames").is_dir())
    assert seqs
    for seq in seqs:
        _check_davis_sequence(seq)


def _check_davis_sequence(seq):
    names = sorted(p.name for p in (seq / "frames").glob("*.jpg"))
    first = cv2.imread(str(seq / "frames" / names[0]))
    cam = ReplayCamera(ReplayCamera.Config(path=str(seq), frame_rate_hz=24.0),
                       model=_model(first.shape[1], first.shape[0]))
    with cam:
        frames = _drain(cam)
        with pytest.raises(EndOfStream):
            cam.grab(timeout_s=1.0)
    assert len(frames) == len(names) > 10
    assert [f.seq for f in frames] == list(range(1, len(names) + 1))
    ts = np.array([f.timestamp_ns for f in frames])
    assert np.all(np.diff(ts) == pytest.approx(1e9 / 24, abs=1))
    # frame k is file k: compare a few against a direct read
    for k in (0, len(names) // 2, len(names) - 1):
        assert np.array_equal(frames[k].image, cv2.imread(str(seq / "frames" / names[k])))
    with pytest.raises(CameraError, match="closed"):
        cam.grab(timeout_s=1.0)


def _state(t_ns: int, north: float) -> VehicleState:
    return VehicleState(timestamp_ns=t_ns, position_ned_m=(north, 1.0, -5.0),
                        velocity_ned_mps=(1.0, 0.0, 0.0), attitude_q=(1.0, 0.0, 0.0, 0.0),
                        home=GeoPoint(47.0, 8.0, 400.0), armed=True, in_air=True,
                        flight_mode=FlightMode.OFFBOARD)


@pytest.mark.parametrize("fmt", ["png", "jpg"])
def test_recorder_to_replay_round_trip(tmp_path, fmt):
    rng = np.random.RandomState(7)
    run = tmp_path / "run1"
    models = {cid: _model(160, 120, cid) for cid in ("wide", "narrow")}
    sent: dict[str, list[Frame]] = {"wide": [], "narrow": []}
    with RunRecorder(run, image_format=fmt) as rec:
        for m in models.values():
            rec.write_camera_model(m)
        for k in range(6):
            t = 2_000_000_000 + k * 33_000_000
            rec.write_state(_state(t - 1_000_000, float(k)))
            for cid in sent:
                img = cv2.resize(rng.randint(0, 255, (6, 8, 3), np.uint8), (160, 120),
                                 interpolation=cv2.INTER_CUBIC)
                f = Frame(img, t + (500_000 if cid == "narrow" else 0), cid, k + 1, 0.004)
                assert rec.write_frame(f)
                sent[cid].append(f)
    assert rec.stats["frames_written"] == 12 and rec.stats["dropped_frames"] == 0
    for cid, frames in sent.items():
        cam = ReplayCamera(ReplayCamera.Config(path=str(run), camera=cid), model=models[cid])
        got = _drain(cam)
        assert [g.seq for g in got] == [f.seq for f in frames]
        assert [g.timestamp_ns for g in got] == [f.timestamp_ns for f in frames]
        assert all(g.exposure_s == 0.004 for g in got)
        for g, f in zip(got, frames):
            if fmt == "png":
                assert np.array_equal(g.image, f.image)
            else:
                assert np.abs(g.image.astype(int) - f.image).mean() < 3
        assert np.allclose(read_camera_model(run, cid).K, models[cid].K)
    states = read_telemetry(run)
    assert [s.position_ned_m[0] for s in states] == [float(k) for k in range(6)]
    assert states[0] == _state(2_000_000_000 - 1_000_000, 0.0)
    hist = telemetry_history(run)
    mid = hist.state_at(2_000_000_000 + 16_000_000)
    assert mid is not None and 0.0 < mid.position_ned_m[0] < 1.0
    with pytest.raises(FileExistsError):
        RunRecorder(run)


def test_replay_pacing_realtime_holds_frames(tmp_path):
    for k in range(4):
        cv2.imwrite(str(tmp_path / f"{k:03d}.png"), np.full((48, 64, 3), k * 40, np.uint8))
    cam = ReplayCamera(ReplayCamera.Config(path=str(tmp_path), pacing="realtime",
                                           frame_rate_hz=20.0), model=_model(64, 48))
    t0 = time.monotonic()
    frames = _drain(cam)
    elapsed = time.monotonic() - t0
    assert len(frames) == 4
    assert elapsed >= 3 / 20 - 0.01  # 3 frame periods after the first
    # a frame further away than the timeout: GrabTimeout, the frame is not consumed
    slow = ReplayCamera(ReplayCamera.Config(path=str(tmp_path), pacing="realtime",
                                            frame_rate_hz=2.0), model=_model(64, 48))
    slow.grab(timeout_s=1.0)
    with pytest.raises(GrabTimeout):
        slow.grab(timeout_s=0.05)
    assert slow.grab(timeout_s=1.0).seq == 2


def test_replay_as_fast_as_consumed_is_deterministic(tmp_path):
    rng = np.random.RandomState(3)
    for k in range(5):
        cv2.imwrite(str(tmp_path / f"img{k}.png"), rng.randint(0, 255, (30, 40, 3), np.uint8))
    a = _drain(ReplayCamera(ReplayCamera.Config(path=str(tmp_path)), model=_model(40, 30)))
    b = _drain(ReplayCamera(ReplayCamera.Config(path=str(tmp_path)), model=_model(40, 30)))
    assert [f.timestamp_ns for f in a] == [f.timestamp_ns for f in b]
    assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b))
    # natural order: img2 before img10 would matter; here names are one digit
    assert a[0].timestamp_ns == 1_000_000_000


def test_corrupted_and_wrong_size_frames_raise_frame_error_and_replay_continues(tmp_path):
    cv2.imwrite(str(tmp_path / "00.png"), np.zeros((30, 40, 3), np.uint8))
    (tmp_path / "01.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    cv2.imwrite(str(tmp_path / "02.png"), np.zeros((31, 40, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "03.png"), np.full((30, 40, 3), 9, np.uint8))
    cam = ReplayCamera(ReplayCamera.Config(path=str(tmp_path)), model=_model(40, 30))
    assert cam.grab(timeout_s=1).seq == 1
    with pytest.raises(FrameError, match="decode"):
        cam.grab(timeout_s=1)
    with pytest.raises(FrameError, match="40x31"):
        cam.grab(timeout_s=1)
    last = cam.grab(timeout_s=1)
    assert last.seq == 4 and last.image[0, 0, 0] == 9
    with pytest.raises(EndOfStream):
        cam.grab(timeout_s=1)
    assert cam.health()["frame_errors"] == 2


def test_video_file_replay(tmp_path):
    path = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
    assert vw.isOpened()
    for k in range(7):
        vw.write(np.full((48, 64, 3), 30 * k, np.uint8))
    vw.release()
    cam = ReplayCamera(ReplayCamera.Config(path=str(path)), model=_model(64, 48))
    frames = _drain(cam)
    assert len(frames) == 7
    assert [round(float(f.image.mean()) / 30) for f in frames] == list(range(7))
    assert frames[1].timestamp_ns - frames[0].timestamp_ns == 40_000_000


def test_recorder_never_lists_a_half_written_frame(tmp_path):
    """A CSV row appears only after its image file is complete (renamed into place)."""
    run = tmp_path / "r"
    rec = RunRecorder(run, queue_frames=2)
    img = np.zeros((960, 1280, 3), np.uint8)
    accepted = sum(rec.write_frame(Frame(img.copy(), 10 + k, "wide", k + 1)) for k in range(50))
    rec.close()
    assert rec.stats["frames_written"] == accepted
    assert rec.stats["dropped_frames"] == 50 - accepted
    rows = (run / "wide" / "frames.csv").read_text().splitlines()[1:]
    assert len(rows) == accepted
    assert not list((run / "wide" / "frames").glob("*.tmp"))
    for row in rows:
        assert (run / "wide" / row.split(",")[3]).stat().st_size > 0
    json.dumps(rec.stats)


def test_recorder_interface_used_by_the_mission_runner(tmp_path):
    """lab/campaign/sim.py uses replay.Recorder(root, models=...), write_frame, write_telemetry."""
    from eaglemission.drivers.cameras.replay.camera import Recorder

    models = {"wide": _model(32, 24, "wide"), "narrow": _model(32, 24, "narrow")}
    rec = Recorder(tmp_path / "run", models=models)
    rec.write_telemetry(_state(5, 1.0))
    rec.write_frame(Frame(np.zeros((24, 32, 3), np.uint8), 7, "narrow", 1))
    rec.close()
    rec.close()  # idempotent
    assert read_camera_model(tmp_path / "run", "narrow").camera_id == "narrow"
    assert read_telemetry(tmp_path / "run")[0].timestamp_ns == 5
    cam = ReplayCamera(ReplayCamera.Config(path=str(tmp_path / "run"), camera="narrow"),
                       model=models["narrow"])
    assert cam.grab(timeout_s=1.0).timestamp_ns == 7
