"""Recording as the mission file's ``recording`` section says (on in the field config, off in
the simulation one): a flight records without ``--record``, a low disk refuses before take-off
(exit 5, one line), ``--dry-run`` reports the free space, a file split by size gives valid
parts that together hold every message once, and the frame counts per camera add up (grabbed
= processed + skipped + dropped). Short simulated flights (the coarse approach times out
after 4 s)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from deployment_helpers import REPO, log_records
from eaglemission.missions.camera_pump import FrameCounts
from mcap.reader import make_reader

from eaglemission.cli import main
from eaglemission.config import MissionFile, load_config
from eaglemission.errors import ConfigError
from eaglemission.flight.run import EXIT_PREFLIGHT, FlightOptions, fly_sync
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.recording.mcap_reader import messages, parts_of
from eaglemission.recording.options import planned
from eaglemission.types import Frame


def _field_like(cfg: MissionFile, folder: Path, **recording: Any) -> Path:
    """The fast simulated mission with a field-like ``recording`` section (relative path)."""
    data = cfg.model_dump(mode="json")
    data["mission"]["params"]["timeouts"]["coarse_approach_s"] = 4.0
    data["recording"] = {"path": "flights/{utc}.mcap", **recording}
    path = folder / "m.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _flat(text: str) -> str:
    return " ".join(text.split())  # the console wraps long lines


def test_the_field_config_records_and_the_simulation_config_does_not() -> None:
    assert load_config(check_plugins=False).recording is None
    rec = load_config(REPO / "configs" / "field_basler_px4.yaml", check_plugins=False).recording
    assert rec is not None and rec.split_mb and rec.min_free_mb > 0
    assert rec.path == str(REPO / "configs" / "flights" / "{utc}.mcap")  # beside the file


def test_a_split_config_recording_holds_every_message_once_and_counts_add_up(
        fast_config: MissionFile, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mission = _field_like(fast_config, tmp_path, split_mb=1.0, min_free_mb=10)
    code = main(["run", str(mission), "--log", str(tmp_path / "x.jsonl")])  # no --record
    out = _flat(capsys.readouterr().out)
    assert code == 3  # FAILSAFE: the coarse approach timed out, as configured
    first = [f for f in (tmp_path / "flights").glob("*.mcap") if f.name.count(".") == 1]
    assert len(first) == 1
    parts = parts_of(first[0])
    assert len(parts) >= 3 and set(parts) == set((tmp_path / "flights").glob("*.mcap"))
    assert parts[1].name == first[0].stem + ".001.mcap"
    for part in parts:  # each part is a valid file (footer, index) readable alone
        with part.open("rb") as f:
            reader = make_reader(f)
            assert reader.get_summary() is not None
            topics = {c.topic for _, c, _ in reader.iter_messages()}
        assert {"/camera/wide/calibration", "/camera/narrow/calibration", "/camera/wide/model",
                "/log/config", "/log/start"} <= topics, part.name
    # together: every message once (the copies each later part starts with left out)
    msgs = list(messages(first[0]))
    keys = [(t, m.log_time, m.sequence, m.data) for t, m in msgs]
    assert len(set(keys)) == len(keys)
    lines = [ln.strip() for ln in (tmp_path / "x.jsonl").read_text().splitlines() if ln.strip()]
    assert sorted(m.data.decode() for t, m in msgs if t.startswith("/log/")) == sorted(lines)
    end = next(r for r in log_records(tmp_path / "x.jsonl") if r["kind"] == "end")
    for cam in (CAMERA_WIDE, CAMERA_NARROW):
        seqs = [m.sequence for t, m in msgs if t == f"/camera/{cam}/image"]
        assert len(seqs) == len(set(seqs)) == end["frames"][cam] > 0
        assert sum(t == f"/camera/{cam}/calibration" for t, _ in msgs) == 1
    # the counts: on the stats channel, in the end record and in run's summary
    stats = json.loads(next(m.data for t, m in msgs if t == "/recorder/stats"))
    assert stats["parts"] == len(parts) and stats["write_errors"] == 0
    assert stats["cameras"] == end["frame_counts"]
    for cam, n in end["frame_counts"].items():
        assert n["grabbed"] == n["processed"] + n["skipped"] + n["dropped"], (cam, n)
        assert n["processed"] == end["frames"][cam] and n["dropped"] == 0  # virtual time
        assert (f"camera {cam}: {n['grabbed']} frames grabbed = {n['processed']} processed + "
                f"{n['skipped']} skipped + {n['dropped']} dropped") in out
    assert f"in {len(parts)} parts" in out
    assert main(["log", str(first[0])]) == 0
    listing = capsys.readouterr().out
    assert f"split recording, {len(parts)} parts" in listing
    assert all(f"  {p.name}: complete" in listing for p in parts)
    assert "camera wide: " in listing and "all parts complete" in listing
    # the last part cut short (a crash in flight): log --recover rebuilds every part
    with parts[-1].open("rb") as f:  # what the last part holds: all a cut in it may lose
        in_last = sum(1 for _ in make_reader(f).iter_messages())
    cut = parts[-1].read_bytes()
    parts[-1].write_bytes(cut[: len(cut) * 2 // 3])
    assert main(["log", "--recover", str(first[0])]) == 0
    said = capsys.readouterr().out.splitlines()
    assert len(said) == len(parts) and "its last complete chunk" in said[-1]
    recovered = sorted((tmp_path / "flights").glob("*.recovered*.mcap"))
    assert len(recovered) == len(parts)
    back = list(messages(first[0].with_name(first[0].stem + ".recovered.mcap")))
    keys_back = [(t, m.log_time, m.sequence, m.data) for t, m in back]
    assert len(keys_back) < len(keys) and keys_back == keys[: len(keys_back)]  # a prefix
    assert len(keys_back) >= len(keys) - in_last  # every earlier part is whole


def test_low_disk_refuses_before_takeoff_with_one_line(
        fast_config: MissionFile, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mission = _field_like(fast_config, tmp_path, min_free_mb=1e12)
    cfg = load_config(mission)
    res = fly_sync(cfg, FlightOptions(hooks=_no_log()))
    assert res.exit_code == EXIT_PREFLIGHT == 5 and res.outcome is None
    assert "\n" not in res.error and res.error.startswith("recording: disk space: only ")
    assert f"MB free at {tmp_path}" in res.error and "recording.min_free_mb 1e+12" in res.error
    assert main(["run", str(mission), "--log", str(tmp_path / "x.jsonl")]) == 5
    err = _flat(capsys.readouterr().err)
    assert "error: recording: disk space: only" in err and str(tmp_path) in err
    assert not (tmp_path / "flights").exists() and not (tmp_path / "x.jsonl").exists()


def _no_log() -> Any:
    from eaglemission.interfaces import MissionHooks

    return MissionHooks()


def test_dry_run_reports_the_free_space_and_record_overrides_the_config(
        fast_config: MissionFile, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mission = _field_like(fast_config, tmp_path, min_free_mb=10)
    assert main(["run", str(mission), "--dry-run"]) == 0
    out = _flat(capsys.readouterr().out)
    assert "[ok] recording: disk space: " in out and f"MB free at {tmp_path}" in out
    # --record FILE.mcap replaces the path, keeps the section's disk check
    low = _field_like(fast_config, tmp_path, min_free_mb=1e12)
    (tmp_path / "elsewhere").mkdir()
    other = tmp_path / "elsewhere" / "f.mcap"
    assert main(["run", str(low), "--dry-run", "--record", str(other)]) == 5
    out = _flat(capsys.readouterr().out)
    assert "[FAIL] recording: disk space: only" in out and f"at {other.parent}" in out
    assert main(["run", str(low), "--dry-run", "--no-record"]) == 0
    assert "recording: disk space" not in capsys.readouterr().out
    assert not (tmp_path / "flights").exists() and not other.exists()


def test_an_existing_recording_is_never_overwritten(fast_config: MissionFile,
                                                    tmp_path: Path) -> None:
    cfg = load_config(_field_like(fast_config, tmp_path, path="f.mcap"))
    (tmp_path / "f.mcap").write_bytes(b"")
    with pytest.raises(ConfigError, match="exists"):
        planned(cfg, None, use_config=True)
    assert planned(cfg, None, use_config=False) is None


def test_frame_counts_count_a_cameras_skipped_frames_from_its_sequence_numbers() -> None:
    import numpy as np

    counts = FrameCounts(["wide"])
    img = np.zeros((2, 2, 3), np.uint8)
    for seq in (1, 2, 5, 9):  # a free-running camera faster than the processing rate
        counts.grabbed(Frame(img, seq, "wide", seq))
    counts.idle("wide")  # not taken for a while: the next gap is no skip
    counts.grabbed(Frame(img, 20, "wide", 20))
    assert counts.as_dict()["wide"] == {"grabbed": 10, "processed": 0, "skipped": 5,
                                        "dropped": 0}


def test_utc_names_never_collide(tmp_path: Path) -> None:
    from datetime import UTC, datetime

    from eaglemission.config import RecordingConfig
    from eaglemission.recording.options import options_from_config

    rec = RecordingConfig(path=str(tmp_path / "{utc}.mcap"))
    now = datetime(2026, 12, 1, 10, 15, 2, tzinfo=UTC)
    first = options_from_config(rec, now=now).path
    assert first.name == "20261201T101502Z.mcap"
    first.write_bytes(b"")
    assert options_from_config(rec, now=now).path.name == "20261201T101502Z-1.mcap"
