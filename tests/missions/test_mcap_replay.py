"""``eaglemission replay FILE.mcap [CONFIG]``: a recorded virtual-time flight replays through the
same detector -> estimator -> state machine to the same setpoints, envelope verdicts and state
changes, bit for bit, for several seeds; another config, or a frame changed in the file, is
reported with its first divergence. ``log --plot`` draws a recording.

The flights are short and small (320x240 cameras, MSS, the coarse approach times out after
3 s) and recorded lossless (``--record-lossless``): they take off, cruise, detect the target,
approach it and fail safe, which exercises every channel the replay answers."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import Writer
from mission_helpers import variant

from eaglemission.cli import main
from eaglemission.commands.replay import replay
from eaglemission.config import MissionFile, load_config
from eaglemission.flight.run import EXIT_REPLAY_DIVERGED, FlightOptions, fly_sync
from eaglemission.recording.mcap_reader import Scan, log_records, scan
from eaglemission.recording.options import RecordOptions

SEEDS = (1, 2)


def small_config(seed: int) -> MissionFile:
    cfg = variant(load_config(check_plugins=False),
                  detector={"type": "mss", "params": {"downscale": 2}}, world_params={"seed": seed})
    data = cfg.model_dump(mode="json")
    data["mission"]["params"]["timeouts"]["coarse_approach_s"] = 3.0
    for cid in ("wide", "narrow"):
        data["cameras"][cid]["resolution_px"] = [320, 240]
    return MissionFile.model_validate(data)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    """One lossless recording per seed (recorded on first use)."""
    tmp = tmp_path_factory.mktemp("replay")

    class Lazy(dict[int, Path]):
        def __missing__(self, seed: int) -> Path:
            path = tmp / f"seed{seed}.mcap"
            res = fly_sync(small_config(seed), FlightOptions(record=RecordOptions(
                path, lossless=True)))
            assert res.outcome is not None and res.recording is not None, res.error
            assert res.recording["frames_dropped"] == 0 and res.recording["write_errors"] == 0
            self[seed] = path
            return path

    return Lazy()


def _kinds(path: Path, kind: str) -> list[dict[str, Any]]:
    return list(log_records(path, (kind,)))


@pytest.mark.parametrize("seed", SEEDS)
def test_a_recorded_flight_replays_to_identical_setpoints_and_state_changes(
        recordings: dict[int, Path], seed: int, capsys: pytest.CaptureFixture[str]) -> None:
    path = recordings[seed]
    setpoints, states = _kinds(path, "setpoint"), _kinds(path, "state")
    # not a trivial flight: it detected the target, approached it on estimates, failed safe
    names = [s["new"] for s in states]
    assert names[:3] == ["TAKEOFF", "CRUISE", "COARSE_APPROACH"] and names[-1] == "FAILSAFE"
    assert len(setpoints) > 100 and any(s["target"] for s in setpoints)
    assert any(d["used"] for d in _kinds(path, "detection"))
    code = main(["replay", str(path)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert f"identical: {len(setpoints)} setpoints, {len(states)} state changes" in out
    # progress while it flies: the file first, then each state change before the verdict
    lines = out.splitlines()
    assert lines[0] == f"replaying {path} ..."
    said = [ln.split()[-1] for ln in lines if ln.startswith("  ") and " s  " in ln]
    assert said[:len(states)] == [s["new"] for s in states]


def test_another_config_reports_its_first_divergence(recordings: dict[int, Path],
                                                     tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    path = recordings[SEEDS[0]]
    data = small_config(SEEDS[0]).model_dump(mode="json")
    data["detector"]["params"]["downscale"] = 1  # the detector at full resolution
    cfg_path = tmp_path / "other.yaml"
    cfg_path.write_text(yaml.safe_dump(data, sort_keys=False))
    code = main(["replay", str(path), str(cfg_path)])
    out = capsys.readouterr().out
    assert code == EXIT_REPLAY_DIVERGED, out
    assert "diverged: recorded" in out and "first divergence at t = " in out
    assert "  recorded: {" in out and "  replayed: " in out
    assert "detections wide:" in out and "setpoints:" in out  # the side-by-side summary


def _with_frame_replaced(src: Path, dst: Path, topic: str, seq: int) -> None:
    """A copy of ``src`` whose image ``seq`` on ``topic`` is a uniform grey frame."""
    schemas: dict[int, int] = {}
    channels: dict[int, tuple[int, str]] = {}
    replaced = 0
    with dst.open("wb") as fh:
        w: Any = Writer(fh)
        w.start(profile="", library="test")
        for rec in scan(src, Scan()):
            if isinstance(rec, Schema) and rec.id not in schemas:
                schemas[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.id not in channels:
                channels[rec.id] = (w.register_channel(rec.topic, rec.message_encoding,
                                                       schemas.get(rec.schema_id, 0)), rec.topic)
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Message):
                cid, t = channels[rec.channel_id]
                data = rec.data
                if t == topic and rec.sequence == seq:
                    img = CompressedImage.FromString(data)
                    old = cv2.imdecode(np.frombuffer(img.data, np.uint8), cv2.IMREAD_COLOR)
                    img.data = cv2.imencode(".png", np.full_like(old, 128))[1].tobytes()
                    data, replaced = img.SerializeToString(), replaced + 1
                w.add_message(cid, log_time=rec.log_time, data=data,
                              publish_time=rec.publish_time, sequence=rec.sequence)
        w.finish()
    assert replaced == 1


def test_the_replay_sees_the_recorded_frames(recordings: dict[int, Path],
                                             tmp_path: Path) -> None:
    """One wide frame greyed out (the last detection before the coarse approach began): the
    replay diverges, no earlier than that frame."""
    path = recordings[SEEDS[0]]
    t_coarse = next(s["t_ns"] for s in _kinds(path, "state") if s["new"] == "COARSE_APPROACH")
    det = [d for d in _kinds(path, "detection")
           if d["camera"] == "wide" and d["used"] and d["frame_t_ns"] <= t_coarse][-1]
    bad = tmp_path / "grey.mcap"
    _with_frame_replaced(path, bad, "/camera/wide/image", det["seq"])
    res = replay(bad)
    cmp = res.comparison
    assert not cmp.identical and cmp.divergence is not None
    assert cmp.divergence.t_ns >= det["frame_t_ns"]
    assert res.comparison.detections["wide"][1] < res.comparison.detections["wide"][0]


def test_log_plot_draws_the_recording(recordings: dict[int, Path], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "flight.png"
    assert main(["log", "--plot", str(out), str(recordings[SEEDS[0]])]) == 0
    assert f"plot written to {out}" in capsys.readouterr().out
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert img is not None and img.shape[0] > 400 and img.shape[1] > 800
    # lines and bands, not a blank canvas: many distinct grey levels, dark ink present
    assert len(np.unique(img)) > 50 and (img < 100).mean() > 0.005


def test_a_file_that_is_no_recording_is_refused(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"not an mcap file")
    assert main(["replay", str(bad)]) == 2
    assert str(bad) in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 2
    assert "no such recording" in capsys.readouterr().err


def test_recorded_vehicle_channels_are_json(recordings: dict[int, Path]) -> None:
    """The vehicle tap's channels: every new state, lookups, commands, parameter reads."""
    topics: dict[str, int] = {}
    for rec in scan(recordings[SEEDS[0]], Scan()):
        if isinstance(rec, Channel):
            topics[rec.topic] = 0
    assert {"/vehicle/state", "/vehicle/state_at", "/vehicle/command",
            "/vehicle/param", "/vehicle/event"} <= set(topics)
    cmds = [r for r in _vehicle(recordings[SEEDS[0]], "/vehicle/command")]
    assert [c["name"] for c in cmds][:2] == ["arm", "takeoff"] and all(c["ok"] for c in cmds)


def _vehicle(path: Path, topic: str) -> list[dict[str, Any]]:
    from eaglemission.recording.mcap_reader import messages

    return [json.loads(m.data) for t, m in messages(path) if t == topic]


def test_compare_reports_the_earliest_divergence_over_the_channels() -> None:
    from eaglemission.recording.compare import compare

    def sp(t: int, n: float) -> dict[str, Any]:
        return {"kind": "setpoint", "t_ns": t, "state": "CRUISE", "setpoint": [n, 0, -5, 0],
                "sent": [n, 0, -5, 0], "goal": [n, 0, -5], "target": None, "latency_ms": 3.0}

    def st(t: int, new: str) -> dict[str, Any]:
        return {"kind": "state", "t_ns": t, "old": "CRUISE", "new": new, "reason": "r"}

    start = {"kind": "start", "t_ns": 1_000_000_000}
    rec = [start, sp(2_000_000_000, 1.0), st(2_500_000_000, "A"), sp(3_000_000_000, 2.0)]
    same = [dict(r, latency_ms=99.0) if r["kind"] == "setpoint" else r for r in rec]
    assert compare(rec, same).identical  # latencies are not compared
    later_sp = [start, sp(2_000_000_000, 1.0), st(2_500_000_000, "A"), sp(3_000_000_000, 2.5)]
    earlier_st = [start, sp(2_000_000_000, 1.0), st(2_400_000_000, "A"), sp(3_000_000_000, 2.5)]
    d = compare(rec, later_sp).divergence
    assert d is not None and (d.channel, d.index, d.t_s) == ("setpoint", 1, 2.0)
    d = compare(rec, earlier_st).divergence  # the state change comes first in time
    assert d is not None and (d.channel, d.index) == ("state", 0)
    assert abs(d.t_s - 1.4) < 1e-9 and d.recorded == {
        "t_ns": 2_500_000_000, "old": "CRUISE", "new": "A", "reason": "r", "action": None}
    d = compare(rec, rec[:-1]).divergence  # the replay has fewer setpoints
    assert d is not None and d.replayed is None and d.channel == "setpoint"
