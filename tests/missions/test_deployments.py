"""Every deployment is a config flown through the one assembly, tested with real
processes: ``eaglemission run`` against ``eaglemission sitl-vehicle`` on a free port, the
replay of a recording, the field path on the genicam wheel's GenTL test producer, an
unreachable autopilot, and Ctrl-C in flight."""

from __future__ import annotations

import csv
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from deployment_helpers import (
    REPO,
    cli,
    free_udp_port,
    log_records,
    mission_file,
    read_status,
    run_env,
    sitl_vehicle,
    viky_field_config,
)
from mission_helpers import variant

pytestmark = [pytest.mark.slow, pytest.mark.machine]  # ports, child processes
ON_GROUND = 1  # MAV_LANDED_STATE_ON_GROUND


def _states(recs: list[dict]) -> list[str]:
    return [r["new"] for r in recs if r["kind"] == "state"]


def _wait_landed(status: Path, timeout_s: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while True:
        st = read_status(status)
        if st["landed_state"] == ON_GROUND and not st["armed"]:
            return st
        if time.monotonic() > deadline:
            raise AssertionError(f"the emulator is not landed and disarmed: {st}")
        time.sleep(0.2)


# The folder recording writes every grabbed frame of both cameras as PNG: at half resolution
# (the same field of view: 640 x 480 pixels of twice the size) this test takes a third of the time.
HALF_RES = {"resolution_px": [640, 480], "pixel_size_um": 7.5}


def test_replay_config_reads_its_frames_from_the_recording(fast_config, tmp_path: Path) -> None:
    from eaglemission.lab.campaign.sim import run_simulation

    cams = {cid: {**cam, **HALF_RES} for cid, cam in fast_config.model_dump()["cameras"].items()}
    cfg = variant(fast_config, cameras=cams, detector={"type": "mss", "params": {"downscale": 1}})
    run = tmp_path / "recordings" / "run1"
    rec = run_simulation(cfg, record_dir=run)
    assert rec.final_state == "DONE"
    recorded = {}
    for cam in ("wide", "narrow"):
        with (run / cam / "frames.csv").open() as f:
            rows = list(csv.DictReader(f))
        recorded[cam] = {int(r["timestamp_ns"]): int(r["seq"]) for r in rows}
        # virtual time: the recorder waits for room, so every grabbed frame is on disk
        assert len(rows) >= rec.result.frames_processed[cam], cam
    # the shipped replay.yaml, with the detector the recording was flown with
    replay = yaml.safe_load((REPO / "configs" / "replay.yaml").read_text())
    replay["detector"] = cfg.detector.model_dump()
    for cam in replay["cameras"].values():
        cam.update(HALF_RES)
    (tmp_path / "replay.yaml").write_text(yaml.safe_dump(replay, sort_keys=False))
    p = subprocess.run(cli("run", "replay.yaml", "--log", "replay.jsonl"),
                       cwd=tmp_path, capture_output=True, text=True, timeout=600, env=run_env())
    assert "Traceback" not in p.stderr, p.stderr
    assert "vehicle: replay (recording recordings/run1, open loop)" in p.stdout
    assert "camera wide: replay" in p.stdout and "camera narrow: replay" in p.stdout
    assert "synthetic" not in p.stdout
    recs = log_records(tmp_path / "replay.jsonl")
    dets = [r for r in recs if r["kind"] == "detection"]
    assert len(dets) > 100
    for d in dets:  # every processed frame is a recorded one: same stamp, same sequence number
        assert recorded[d["camera"]].get(d["frame_t_ns"]) == d["seq"], d
    for cam in ("wide", "narrow"):
        n = sum(d["camera"] == cam for d in dets)
        assert 0 < n <= len(recorded[cam])
    # open loop, same frames, same virtual clock: the replayed mission takes the same course
    assert _states(recs) == [s for _, s, _ in rec.result.states[1:]]
    assert p.returncode == 0, p.stdout + p.stderr


def test_mavsdk_config_flies_against_a_sitl_vehicle_process(tmp_path: Path) -> None:
    port = free_udp_port()
    url = f"udpin://127.0.0.1:{port}"
    mission = mission_file(tmp_path, "mavsdk.yaml", vehicle={
        "_replace": True, "type": "mavsdk", "params": {"url": url, "connect_timeout_s": 20}})
    status = tmp_path / "emulator.json"
    with sitl_vehicle(REPO / "configs" / "sitl_synthetic.yaml", port, status):
        p = subprocess.run(cli("run", str(mission), "--yes", "--log", "run.jsonl",
                               "--plot", "run.png", "--record", "run.mcap"),
                           cwd=tmp_path, capture_output=True, text=True, timeout=400,
                           env=run_env())
        st = _wait_landed(status)
    assert "Traceback" not in p.stderr, p.stderr
    assert f"vehicle: mavsdk (url {url})" in p.stdout
    assert "ground truth: HIL_STATE_QUATERNION" in p.stdout
    assert "clock: wall clock" in p.stdout
    recs = log_records(tmp_path / "run.jsonl")
    states = _states(recs)
    assert "GRASP_READY" in states and states[-1] == "DONE", (states, p.stdout[-2000:])
    ev = [r for r in recs if r["kind"] == "evaluation"][-1]
    assert ev["judged_on"] == "truth" and ev["landed"], ev
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    assert (tmp_path / "run.png").stat().st_size > 10_000
    assert abs(st["true_position_ned_m"][2]) < 0.2
    # the real-time recording replays in virtual time through the same chain: not identical
    # (the replay asks at other instants than the wall-clock flight did), but it flies the same
    # course and says where it first departs, with the side-by-side summary
    r = subprocess.run(cli("replay", "run.mcap"), cwd=tmp_path, capture_output=True, text=True,
                       timeout=400, env=run_env())
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode in (0, 7), r.stdout[-3000:] + r.stderr[-3000:]
    if r.returncode == 7:
        assert "first divergence" in r.stdout and "GRASP_READY" in r.stdout, r.stdout[-3000:]
    else:
        assert "identical" in r.stdout


def test_unreachable_autopilot_fails_within_connect_timeout_with_one_line(tmp_path: Path) -> None:
    port = free_udp_port()  # nobody sends there
    mission = mission_file(tmp_path, "nobody.yaml", vehicle={
        "_replace": True, "type": "mavsdk",
        "params": {"url": f"udpin://127.0.0.1:{port}", "connect_timeout_s": 3}})
    t0 = time.monotonic()
    p = subprocess.run(cli("run", str(mission), "--yes"), capture_output=True, text=True,
                       timeout=120, env=run_env())
    elapsed = time.monotonic() - t0
    assert p.returncode == 4, p.stdout + p.stderr
    errors = [line for line in p.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "no autopilot heard" in errors[0], p.stderr
    assert "Traceback" not in p.stderr
    assert "exit 4 (connection failed) after" in p.stdout
    # the flight's own wait is bounded by connect_timeout_s (the rest is Python start-up)
    flight_s = float(p.stdout.split("exit 4 (connection failed) after ")[1].split(" s")[0])
    assert 2.9 <= flight_s <= 3.0 + 2.5, flight_s
    assert elapsed < 60


@pytest.mark.parametrize("action", ["land", "hold"])
def test_sigint_in_flight_commands_the_configured_stop(tmp_path: Path, action: str) -> None:
    port = free_udp_port()
    mission = mission_file(
        tmp_path, "int.yaml",
        vehicle={"_replace": True, "type": "mavsdk",
                 "params": {"url": f"udpin://127.0.0.1:{port}", "connect_timeout_s": 20}},
        safety={"on_interrupt": action, "interrupt_timeout_s": 60})
    status = tmp_path / "emulator.json"
    log = tmp_path / "int.jsonl"
    with sitl_vehicle(REPO / "configs" / "sitl_synthetic.yaml", port, status):
        proc = subprocess.Popen(cli("run", str(mission), "--yes", "--log", str(log),
                                    "--plot", str(tmp_path / "int.png")),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=run_env())
        try:
            deadline = time.monotonic() + 120
            while "CRUISE" not in _states(log_records(log)) if log.exists() else True:
                assert proc.poll() is None, proc.communicate()
                assert time.monotonic() < deadline, "never reached CRUISE"
                time.sleep(0.2)
            time.sleep(1.0)
            airborne = read_status(status)
            assert airborne["armed"] and -airborne["true_position_ned_m"][2] > 2.0, airborne
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
        final = read_status(status)
    assert proc.returncode == 130, out[-2000:] + err[-2000:]
    assert "Traceback" not in err and "Task exception was never retrieved" not in err, err
    assert f"SIGINT: safe stop ({action}) in progress" in out
    recs = log_records(log)
    end = [r for r in recs if r["kind"] == "end"]
    assert end and end[-1]["reason"] == "interrupted by SIGINT" and end[-1]["action"] == action
    assert (tmp_path / "int.png").exists()
    if action == "land":
        assert final["landed_state"] == ON_GROUND and not final["armed"], final
    else:
        assert final["mode"] == "HOLD" and final["armed"], final
        assert -final["true_position_ned_m"][2] > 2.0, final


def test_field_path_on_the_gentl_test_producer_and_the_emulator(tmp_path: Path) -> None:
    port = free_udp_port()
    data = viky_field_config(tmp_path, port)
    # the target is a red box; viky's test pattern is a 20 px green or blue square on white:
    # no target in view, so the route is flown to its end
    data["target"]["color_bgr"] = [30, 40, 210]
    data["mission"]["route"] = [{"north_m": 0.0, "east_m": 0.0}, {"north_m": 12.0, "east_m": 0.0}]
    mission = tmp_path / "field_test.yaml"
    mission.write_text(yaml.safe_dump(data, sort_keys=False))
    v = subprocess.run(cli("validate", str(mission)), capture_output=True, text=True, timeout=120)
    assert v.returncode == 0, v.stderr
    status = tmp_path / "emulator.json"
    log = tmp_path / "field.jsonl"
    with sitl_vehicle(mission, port, status):
        p = subprocess.run(cli("run", str(mission), "--yes", "--log", str(log)),
                           capture_output=True, text=True, timeout=400, env=run_env())
        final = _wait_landed(status, 60.0)
    assert "Traceback" not in p.stderr, p.stderr
    assert "camera wide: genicam" in p.stdout and "camera narrow: genicam" in p.stdout
    assert "800x600 px" in p.stdout and "synthetic" not in p.stdout
    # the cameras are real GenTL devices; only the emulator (standing in for the autopilot)
    # knows where it truly is, and says so
    assert "ground truth: HIL_STATE_QUATERNION" in p.stdout
    recs = log_records(log)
    states = _states(recs)
    assert states[:3] == ["TAKEOFF", "CRUISE", "FAILSAFE"], states
    end = [r for r in recs if r["kind"] == "end"][-1]
    assert end["reason"] == "route finished without a confirmed target", end
    assert end["action"] == "return" and end["completed"]
    assert {"start", "telemetry", "detection", "setpoint", "command", "end",
            "evaluation"} <= {r["kind"] for r in recs}
    # the route was flown: the reported position went to its end, then home
    north = [r["position_ned_m"][0] for r in recs if r["kind"] == "telemetry"]
    assert max(north) > 10.0 and abs(final["true_position_ned_m"][0]) < 2.0
    assert p.returncode == 3, p.stdout[-2000:] + p.stderr[-2000:]


def test_link_faults_travel_the_emulators_udp_path_in_real_time(tmp_path: Path) -> None:
    """``run --vehicle emulator`` with link faults: the mavsdk vehicle's fault relay duplicates,
    reorders and re-stamps the real MAVLink traffic; the driver and the mission notice each
    and the flight still completes (all three are tolerable: docs/faults.md)."""
    binned = {"resolution_px": [640, 480], "pixel_size_um": 7.5}
    base = yaml.safe_load((REPO / "configs" / "sitl_synthetic.yaml").read_text())
    cams = {c: {**v, **binned} for c, v in base["cameras"].items()}
    mission = mission_file(tmp_path, "faults.yaml", cameras={"_replace": True, **cams},
                           detector={"params": {"preset": "field", "use_dynamic": False,
                                                "downscale": 1}},
                           faults={"inject": [
                               {"kind": "link_duplicate", "at_state": "CRUISE", "delay_s": 0.5,
                                "duration_s": 1.5},
                               {"kind": "link_reorder", "at_state": "CRUISE", "delay_s": 2.5,
                                "duration_s": 1.5},
                               {"kind": "autopilot_clock_jump", "at_state": "CRUISE",
                                "delay_s": 4.5, "duration_s": 1.0, "size": -5.0}]})
    p = subprocess.run(cli("run", str(mission), "--vehicle", "emulator", "--log", "run.jsonl"),
                       cwd=tmp_path, capture_output=True, text=True, timeout=400, env=run_env())
    assert "Traceback" not in p.stderr, p.stderr
    recs = log_records(tmp_path / "run.jsonl")
    states = _states(recs)
    assert "GRASP_READY" in states and states[-1] == "DONE", (states, p.stdout[-2000:])
    assert p.returncode == 0, p.stdout[-3000:]
    injected = [r["fault"] for r in recs if r["kind"] == "fault_injected"]
    assert injected == ["link_duplicate", "link_reorder", "autopilot_clock_jump"]
    t_dup = next(r["t_ns"] for r in recs if r.get("fault") == "link_duplicate")
    seen = {r["data"]["problem"] for r in recs if r["kind"] == "event"
            and r.get("event_kind") == "time_base" and r["t_ns"] >= t_dup}
    assert {"telemetry_duplicate", "telemetry_out_of_order"} <= seen, seen
    assert any(r["kind"] == "fault_detected" and r["what"] == "autopilot_clock_jump"
               for r in recs), "the mission re-anchors on the jump"
    ev = [r for r in recs if r["kind"] == "evaluation"][-1]
    assert ev["judged_on"] == "truth" and ev["landed"] and not ev["violations"], ev


def test_a_world_fault_is_refused_on_the_emulator_with_its_path(tmp_path: Path) -> None:
    mission = mission_file(tmp_path, "gps.yaml", faults={"inject": [
        {"kind": "gps_loss", "at_s": 5.0, "duration_s": 2.0}]})
    p = subprocess.run(cli("run", str(mission), "--vehicle", "emulator"), cwd=tmp_path,
                       capture_output=True, text=True, timeout=120, env=run_env())
    out = p.stdout + p.stderr
    assert p.returncode == 2, out[-2000:]
    assert "faults.inject.0.kind" in out and "gps_loss" in out and "Traceback" not in out
