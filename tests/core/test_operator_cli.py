"""What an operator meets on the command line: a missing extra is one line and exit 2, the dry
run prints every check (ok / warn / FAIL) past a failure and never says DONE, ``log`` refuses
a file that is not MCAP, ``validate`` warns about what a field config still has from the
template, the campaign's exit code, the recording's expected size, compile progress, and lines
into a pipe are never wrapped."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from eaglemission.cli import main
from eaglemission.config import MissionFile, load_config

REPO = Path(__file__).resolve().parents[2]
FIELD = REPO / "configs" / "field_basler_px4.yaml"


def _write(data: dict[str, Any], path: Path) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _sim(**sections: Any) -> dict[str, Any]:
    data = load_config(check_plugins=False).model_dump(mode="json")
    data["detector"] = {"type": "mss", "params": {"downscale": 2}}  # fast, no compilation
    data.update(sections)
    return data


# -- extras ------------------------------------------------------------------------------------
def test_sitl_vehicle_without_pymavlink_is_one_line_and_exit_2() -> None:
    """A subprocess in which pymavlink and mavsdk cannot be imported (as on the base install)."""
    code = ("import sys; sys.modules['pymavlink'] = None; sys.modules['mavsdk'] = None\n"
            "from eaglemission.cli import main; sys.exit(main(['sitl-vehicle', "
            "'--duration-s', '1']))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 2, p.stderr
    assert p.stderr.strip().splitlines() == [
        "error: sitl-vehicle needs the [mavsdk] extra (mavsdk, pymavlink not installed): "
        "pip install 'eaglemission[mavsdk]'"]
    assert "Traceback" not in p.stderr


@pytest.mark.parametrize(("blocked", "argv", "needs"), [
    ("mavsdk", ["run", str(FIELD), "--dry-run"], "vehicle.type mavsdk needs the [mavsdk]"),
    ("harvesters", ["run", str(FIELD), "--vehicle", "simulated", "--dry-run"],
     "cameras.wide.type genicam needs the [genicam]"),
    ("foxglove", ["run", "--live", "--no-record"], "run --live"),
    ("mavsdk", ["run", "--vehicle", "emulator"], "run --vehicle emulator needs the [mavsdk]"),
    ("ray", ["campaign", "--executor", "ray", "--runs", "1"],
     "campaign --executor ray needs the [ray]"),
    ("pymavlink", ["campaign", "--vehicle", "emulator", "--runs", "1"],
     "campaign --vehicle emulator needs the [mavsdk]"),
])
def test_a_command_needing_a_missing_extra_says_which_and_exits_2(
        blocked: str, argv: list[str], needs: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, blocked, None)  # not importable: find_spec gives None
    assert main(argv) == 2
    cap = capsys.readouterr()
    err = [line for line in cap.err.splitlines() if line.strip()]
    assert len(err) == 1 and needs in err[0], cap
    assert "pip install 'eaglemission[" in err[0]
    assert "DONE" not in cap.out


def test_the_field_extra_installs_cameras_and_autopilot() -> None:
    import tomllib

    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    assert extras["field"] == ["eaglemission[mavsdk,genicam]"]


# -- the dry run -------------------------------------------------------------------------------
def test_the_dry_run_prints_every_check_past_a_failure_and_never_says_done(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = _sim()
    data["cameras"]["narrow"] = {**data["cameras"]["narrow"], "type": "replay",
                                 "params": {"path": str(tmp_path / "no-such-folder")}}
    mission = _write(data, tmp_path / "m.yaml")
    assert main(["run", str(mission), "--dry-run"]) == 5
    out = capsys.readouterr().out.splitlines()
    checks = [line for line in out if line.startswith("  [")]
    marks = [line.split("]")[0][3:] for line in checks]
    failed = [i for i, m in enumerate(marks) if m == "FAIL"]
    assert len(failed) == 1 and checks[failed[0]].startswith("  [FAIL] camera narrow: open: ")
    after = checks[failed[0] + 1:]  # the failure stopped nothing
    for name in ("camera wide: frame", "vehicle: link", "vehicle: battery",
                 "vehicle: downward rangefinder", "autopilot parameters"):
        assert any(name in line for line in after), (name, checks)
    assert "warn" in marks  # the rangefinder's reading on the ground
    verdict = [line for line in out if line.startswith("dry run ")]
    assert len(verdict) == 1 and verdict[0].startswith("dry run FAILED: 1 of ")
    assert verdict[0].endswith("nothing was armed")
    assert out[-1].startswith("exit 5 (dry run failed: nothing armed)")
    assert not any("DONE" in line for line in out)


def test_a_passing_dry_run_has_its_own_exit_line(capsys: pytest.CaptureFixture[str],
                                                  tmp_path: Path) -> None:
    assert main(["run", str(_write(_sim(), tmp_path / "m.yaml")), "--dry-run"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-1].startswith("exit 0 (dry run passed: nothing armed)")
    assert not any("DONE" in line for line in out)


def test_run_flies_the_manipulator_named_on_the_command_line(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    mission = str(_write(_sim(), tmp_path / "m.yaml"))
    assert main(["run", mission, "--manipulator", "simulated_arm", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "manipulator: simulated_arm (simulated X-Y-Z arm: box +-10 x +-10 x +-8 cm" in out
    assert main(["run", mission, "--manipulator", "no_such_arm", "--dry-run"]) == 2
    assert "no manipulator plugin named 'no_such_arm'" in capsys.readouterr().err


def test_a_missing_serial_device_is_named_with_the_fix(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("mavsdk")
    data = _sim(vehicle={"type": "mavsdk", "params": {
        "url": f"serial://{tmp_path}/ttyACM9:921600", "connect_timeout_s": 5}})
    assert main(["run", str(_write(data, tmp_path / "m.yaml"))]) == 4
    cap = capsys.readouterr()
    assert (f"error: vehicle: {tmp_path}/ttyACM9 not found: plug in the autopilot (or fix "
            "vehicle.params.url)") in cap.err.splitlines()
    assert "None" not in cap.err


def test_serial_problem_names_the_device() -> None:
    from eaglemission.drivers.vehicles.mavsdk.support import serial_problem

    assert serial_problem("serial:///dev/nonexistent-tty:57600") == (
        "/dev/nonexistent-tty not found: plug in the autopilot (or fix vehicle.params.url)")
    assert serial_problem("serial:///dev/null:57600") is None  # there, and openable
    assert serial_problem("udpin://0.0.0.0:14540") is None


# -- validate ----------------------------------------------------------------------------------
def test_validate_warns_about_what_the_field_template_still_has(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["validate", str(FIELD)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert any(line.startswith("warning: cameras.wide.params.serial_number: '40000001' is a "
                               "placeholder") for line in err), err
    assert any("cameras.narrow.calibration_file:" in line and "nominal example" in line
               for line in err)
    assert any(line.startswith("warning: target.appearance_image:") and "red_box.jpg" in line
               and "simulator's example target" in line for line in err)


def test_validate_warns_about_a_missing_calibration_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = yaml.safe_load(FIELD.read_text())
    data["cameras"]["wide"]["params"]["serial_number"] = "24031975"
    data["cameras"]["wide"]["calibration_file"] = None
    data["cameras"]["wide"]["focal_length_mm"] = 2.8
    data["cameras"]["narrow"]["calibration_file"] = str(REPO / "configs/calib/narrow.yaml")
    data["target"].pop("appearance_image")
    assert main(["validate", str(_write(data, tmp_path / "f.yaml"))]) == 0
    err = capsys.readouterr().err
    assert "cameras.wide.calibration_file: none: the lens' nominal intrinsics" in err
    assert "cameras.wide.params.serial_number" not in err
    assert "target.appearance_image" not in err
    assert main(["validate"]) == 0  # the simulation: nothing to warn about
    assert "warning" not in capsys.readouterr().err


# -- log -----------------------------------------------------------------------------------------
def test_log_refuses_a_file_that_is_not_mcap(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    jsonl = tmp_path / "run.jsonl"
    jsonl.write_text('{"kind":"start","t_s":1.0}\n')
    for argv in (["log", str(jsonl)], ["log", "--recover", str(jsonl)]):
        assert main(argv) == 2
        cap = capsys.readouterr()
        assert cap.out == "" and len(cap.err.strip().splitlines()) == 1
        assert "not an MCAP recording" in cap.err and "JSON-lines mission log" in cap.err
    assert not list(tmp_path.glob("*.mcap"))  # nothing "recovered"
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert main(["log", str(empty)]) == 2
    assert "empty file" in capsys.readouterr().err


# -- campaign ------------------------------------------------------------------------------------
@pytest.mark.parametrize(("runs", "missed", "require", "code"), [
    (10, 0, None, 0), (10, 1, None, 1), (10, 1, 0.9, 0), (10, 2, 0.9, 1), (1, 1, 0.0, 0)])
def test_campaign_verdict(runs: int, missed: int, require: float | None, code: int,
                          capsys: pytest.CaptureFixture[str]) -> None:
    from eaglemission.lab.campaign.cli import verdict

    assert verdict(runs, missed, require) == code
    cap = capsys.readouterr()
    line = (cap.out or cap.err).strip()
    assert line.startswith("passed: " if code == 0 else "FAILED: ")
    assert f"{runs - missed}/{runs} runs" in line


def test_campaign_rejects_a_require_outside_0_1(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["campaign", "--runs", "1", "--require", "1.5"]) == 2
    assert "--require 1.5" in capsys.readouterr().err


# -- recording size ------------------------------------------------------------------------------
def test_the_recording_size_follows_resolution_rate_and_format(tmp_path: Path) -> None:
    from eaglemission.recording.options import RecordOptions, expected_size

    px = [1280 * 960, 1280 * 960]
    jpeg = expected_size(RecordOptions(tmp_path / "a.mcap"), px, 8.0, 600.0)
    png = expected_size(RecordOptions(tmp_path / "a.mcap", lossless=True), px, 8.0, 600.0)
    q95 = expected_size(RecordOptions(tmp_path / "a.mcap", jpeg_quality=95), px, 8.0, None)
    assert 3.0 < jpeg[0] < 6.0  # MB/s: the simulated flight recorded 2 MB/s at q75
    assert png[0] == pytest.approx(jpeg[0] * 2.0 / 0.21)
    assert jpeg[1] == pytest.approx(jpeg[0] * 600.0) and q95[1] is None
    assert jpeg[0] < q95[0] < png[0]
    half = expected_size(RecordOptions(tmp_path / "a.mcap"), px[:1], 4.0, None)
    assert half[0] == pytest.approx(jpeg[0] / 4)


def test_record_lossless_says_so_before_take_off(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    mission = _write(_sim(), tmp_path / "m.yaml")
    rec = tmp_path / "f.mcap"
    main(["run", str(mission), "--record", str(rec), "--record-lossless", "--dry-run"])
    out = capsys.readouterr().out.splitlines()
    assert out[1].startswith("--record-lossless: PNG frames, about 10 times")
    [size] = [line for line in out if line.startswith(f"recording {rec}: PNG (lossless")]
    assert "2 cameras (1280x960, 1280x960 px)" in size and "per second of flight" in size
    assert "if the mission runs to its timeouts" in size


# -- progress and the console ----------------------------------------------------------------------
def test_compile_progress_says_when_numba_compiles() -> None:
    from numba import njit

    from eaglemission.flight.progress import compile_progress

    def kernel(x: float) -> float:  # a fresh function: compiled, never in the cache
        return x * 2.0 + 1.0

    lines: list[str] = []
    with compile_progress(lines.append, every_s=0.05) as watch:
        assert njit(kernel)(1.0) == 3.0
    assert lines[0].startswith("compiling numba kernels (first run only")
    assert watch.compiled == 1
    assert lines[-1].startswith("compiled 1 numba kernels in ")
    lines.clear()
    with compile_progress(lines.append, every_s=0.05):
        pass  # nothing compiled: nothing said
    assert lines == []


def test_waiting_ticks_on_the_host_clock() -> None:
    import time

    from eaglemission.flight.progress import waiting

    lines: list[str] = []
    with waiting(lines.append, "the autopilot on udpin://0.0.0.0:14540", every_s=0.05):
        time.sleep(0.18)
    assert lines[:2] == ["waiting for the autopilot on udpin://0.0.0.0:14540 ... 0 s"] * 2


def test_lines_into_a_pipe_are_not_wrapped() -> None:
    code = ("from eaglemission.commands import console\n"
            "console().print('word ' * 60, markup=False)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=60)
    assert p.stdout.count("\n") == 1 and p.stdout.count("word") == 60


def test_run_and_log_share_one_time_base(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """The state changes' times in `run` and in `log` of its recording: seconds since the
    mission's start (the virtual clock starts at 1 s)."""
    data = _sim()
    data["mission"]["params"]["timeouts"]["coarse_approach_s"] = 3.0  # a short flight
    mission = _write(data, tmp_path / "m.yaml")
    rec = tmp_path / "f.mcap"
    main(["run", str(mission), "--record", str(rec)])
    ran = [line.split()[:3] for line in capsys.readouterr().out.splitlines()
           if line.strip().endswith(")") and " s  " in line and line.startswith("  ")]
    assert main(["log", str(rec)]) == 0
    out = capsys.readouterr().out.splitlines()
    i = next(k for k, line in enumerate(out) if line.startswith("state changes"))
    logged = [line.split()[:2] + [line.split()[4]] for line in out[i + 1:i + 1 + len(ran)]]
    assert ran and logged == ran, (ran, logged)


def test_mission_file_helpers_are_valid() -> None:
    MissionFile.model_validate(_sim())


def test_warm_up_flies_the_simulation_with_the_configs_kernels() -> None:
    from eaglemission.commands.warm_up import warm_up_config

    field = load_config(FIELD, check_plugins=False)
    cfg = warm_up_config(field)
    assert cfg.detector == field.detector and cfg.estimators == field.estimators
    assert cfg.vehicle.type == "simulated"  # nothing real is touched
    assert {cfg.cameras.wide.type, cfg.cameras.narrow.type} == {"synthetic"}
