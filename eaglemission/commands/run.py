"""``eaglemission run [CONFIG]``: fly what the mission file says, through the assembly.

Without CONFIG it flies the embedded ``configs/sitl_synthetic.yaml`` (simulated vehicle +
synthetic cameras, virtual time). ``--vehicle emulator`` is a shortcut: the same file with its
vehicle replaced by the ``mavsdk`` vehicle at a PX4-like emulator (``eaglemission sitl-vehicle``,
started here as its own process on a free port). Exit codes: README, "Exit codes".
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from importlib import resources
from pathlib import Path
from typing import Any

from eaglemission.commands import Command

EMULATOR_START_TIMEOUT_S = 20.0


def _add(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="mission YAML (default: embedded sitl_synthetic.yaml)")
    p.add_argument("--vehicle", choices=("simulated", "emulator"), default=None,
                   help="override the file's vehicle: simulated (in-process, virtual time) or "
                        "emulator (the mavsdk vehicle against `eaglemission sitl-vehicle` "
                        "started on a free port; real time)")
    p.add_argument("--plot", metavar="PNG", help="draw trajectory, target and state changes")
    p.add_argument("--record", metavar="FILE.mcap|DIR",
                   help="FILE.mcap: record the flight as MCAP (every processed frame, both "
                        "calibrations, every log record: docs/recording.md); DIR: both camera "
                        "streams + telemetry in the replay format (configs/replay.yaml)")
    p.add_argument("--record-quality", metavar="Q", type=int, default=None,
                   help="JPEG quality of the MCAP recording's images (1-100; default the "
                        "config's recording.quality, else 75)")
    p.add_argument("--record-lossless", action="store_true",
                   help="PNG images in the MCAP recording instead of JPEG: larger, and "
                        "`eaglemission replay` reproduces the flight exactly")
    p.add_argument("--no-record", action="store_true",
                   help="do not record, even when the config's `recording` section says so")
    p.add_argument("--live", metavar="HOST:PORT", nargs="?", const="",
                   help="serve the flight live in Foxglove (the recording's channels over the "
                        "Foxglove WebSocket protocol, throttled thumbnails and telemetry; "
                        "default 127.0.0.1:8765 or the config's live.listen; docs/recording.md)")
    p.add_argument("--no-live", action="store_true",
                   help="do not serve live, even when the config's `live` section says so")
    p.add_argument("--log", metavar="FILE", help="JSON-lines mission log (default: none)")
    p.add_argument("--realtime", action="store_true",
                   help="run at wall-clock speed even when everything could run in virtual time")
    p.add_argument("--detector", metavar="NAME",
                   help="fly with this detector plugin instead of the config's (e.g. mss)")
    p.add_argument("--manipulator", metavar="TYPE",
                   help="fly with this manipulator plugin instead of the config's (e.g. "
                        "simulated_arm; the config's params when it names the same type, else "
                        "the plugin's defaults: docs/manipulators.md)")
    p.add_argument("--dry-run", action="store_true",
                   help="open the cameras, grab and check a frame each, connect, check home, "
                        "GPS, rangefinder and the autopilot's failsafe parameters; never arm")
    p.add_argument("--yes", action="store_true",
                   help="do not ask before arming a real (non-simulated) vehicle")


def _print(console: Any, text: str) -> None:
    console.print(text, markup=False, highlight=False)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def emulator_process(mission_path: str | None, status_json: str | None = None, *,
                     mission_yaml: str | None = None) -> Iterator[str]:
    """Start ``eaglemission sitl-vehicle`` for a mission file (or the mission's YAML text,
    ``mission_yaml``, through its standard input: no file to leave behind) on a free port, as
    its own process; yields the MAVSDK URL to connect to; stops it (SIGTERM, then SIGKILL) on
    exit. It also stops itself when this process is gone (killed before it could stop it)."""
    if (mission_path is None) == (mission_yaml is None):
        raise ValueError("emulator_process: give mission_path or mission_yaml, not both")
    port = _free_udp_port()
    cmd = [sys.executable, "-m", "eaglemission.cli", "sitl-vehicle",
           "--mission", "-" if mission_path is None else mission_path,
           "--mavlink", f"udpout://127.0.0.1:{port}", "--exit-with-pid", str(os.getpid())]
    if status_json:
        cmd += ["--status-json", status_json]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL if mission_yaml is None else subprocess.PIPE,
                            start_new_session=True)
    if mission_yaml is not None and proc.stdin is not None:
        with proc.stdin:
            try:
                proc.stdin.write(mission_yaml.encode("utf-8"))
            except BrokenPipeError:
                pass  # it exited already: its stderr says why, the connection will time out
    try:
        yield f"udpin://127.0.0.1:{port}"
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5.0)
        if proc.stderr is not None:
            proc.stderr.close()


def _mission_file_path(config: str | None) -> tuple[str, Any]:
    """A path to the mission file (the embedded one is written to a temporary file)."""
    if config is not None:
        return config, None
    from eaglemission.config import DEFAULT_CONFIG

    tmp = tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False)  # noqa: SIM115
    tmp.write(resources.files("eaglemission.configs").joinpath(DEFAULT_CONFIG).read_text("utf-8"))
    tmp.close()
    return tmp.name, tmp


def _confirm(question: str) -> bool:
    if not sys.stdin.isatty():
        sys.stderr.write(f"{question} -- no terminal to answer on: pass --yes to fly "
                         "without asking\n")
        return False
    try:
        answer = input(f"{question} [y/N] ")
    except EOFError:
        return False
    return answer.strip().lower() in ("y", "yes")


def _record_options(section: Any, path: Path, quality: int | None, lossless: bool = False
                    ) -> Any:
    """``--record FILE.mcap``: the config's ``recording`` settings (quality, splitting, disk
    check) with this path; ``--record-quality`` over the config's quality."""
    from eaglemission.recording.options import RecordOptions

    if section is None:
        return RecordOptions(path, jpeg_quality=75 if quality is None else quality,
                             lossless=lossless)
    return RecordOptions(path, jpeg_quality=section.quality if quality is None else quality,
                         split_mb=section.split_mb, min_free_mb=section.min_free_mb,
                         lossless=lossless)


def _live_options(args: argparse.Namespace, section: Any) -> Any:
    """The flight's :class:`~eaglemission.recording.live.LiveOptions` (None: not live); raises
    ValueError for a bad ``--live`` or ``live.listen``."""
    from eaglemission.recording import live
    if args.no_live or (args.live is None and section is None):
        return None
    if args.live and (args.live.lower().endswith((".yaml", ".yml")) or Path(args.live).is_file()):
        raise ValueError(f"--live {args.live}: that is a file, not HOST:PORT; put the mission "
                         "file before --live, or write --live=HOST:PORT")
    return live.options_from_config(section, args.live or None)


def _run(args: argparse.Namespace) -> int:
    from eaglemission import extras
    from eaglemission.commands import console as make_console
    from eaglemission.commands.checks import run_checks
    from eaglemission.config import MissionFile, load_config
    from eaglemission.errors import ConfigError, EagleMissionError
    from eaglemission.flight import assembly, run
    from eaglemission.interfaces import MissionHooks

    console = make_console()
    err = make_console(stderr=True)
    try:
        cfg = load_config(args.config)
        problems = run_checks(cfg)
        if problems:
            raise ConfigError(problems, source=args.config or "<embedded>")
    except ConfigError as exc:
        _print(err, f"invalid: {exc}")
        return run.EXIT_CONFIG
    data = cfg.model_dump()
    if args.detector:
        data["detector"] = {"type": args.detector, "params": {}}
    if args.manipulator:
        same = data["manipulator"]["type"] == args.manipulator
        data["manipulator"] = {"type": args.manipulator,
                               "params": data["manipulator"]["params"] if same else {}}
    if args.vehicle == "simulated":
        data["vehicle"] = {"type": "simulated", "params": {}}
    if args.record_quality is not None and data.get("recording"):
        data["recording"]["quality"] = args.record_quality
    try:
        live_options = _live_options(args, cfg.live)
        if live_options is not None:
            extras.require("live", "run --live (or the config's live section)")
        if args.vehicle == "emulator":
            extras.require("mavsdk", "run --vehicle emulator")
        extras.require_for(assembly.part_classes(MissionFile.model_validate(data)))
    except (ValueError, extras.MissingExtra) as exc:
        _print(err, f"error: {exc}")
        return run.EXIT_CONFIG
    from eaglemission.commands.checks import hardware_warnings

    for w in hardware_warnings(MissionFile.model_validate(data)):
        _print(err, f"warning: {w}")
    source = args.config or "<embedded sitl_synthetic.yaml>"
    _print(console, f"eaglemission run {source}" + (" --dry-run (checks only: nothing is armed)"
                                                    if args.dry_run else ""))
    if args.record_lossless:
        _print(console, "--record-lossless: PNG frames, about 10 times the size of a JPEG "
                        "recording (the expected size is said before take-off)")

    def on_header(lines: list[str]) -> None:
        for line in lines:
            _print(console, f"  {line}")

    def on_state(t_s: float, state: str, reason: str, action: str) -> None:
        extra = f" -> {action}" if action else ""
        _print(console, f"  {t_s:7.2f} s  {state:<16} ({reason}{extra})")

    recorder = None
    hooks_kw: dict[str, Any] = {}
    record_mcap = None
    if args.record and args.record.lower().endswith(".mcap"):
        if Path(args.record).exists():
            _print(err, f"error: --record {args.record}: exists (recordings are never "
                        "overwritten): choose a new name")
            return run.EXIT_CONFIG
        if args.record_quality is not None and not 1 <= args.record_quality <= 100:
            _print(err, "error: --record-quality: 1..100")
            return run.EXIT_CONFIG
        record_mcap = _record_options(cfg.recording, Path(args.record), args.record_quality,
                                      args.record_lossless)
    elif args.record:
        from eaglemission.recording.folder import RunRecorder

        try:
            virtual = not (args.realtime or args.vehicle == "emulator"
                           or assembly.plan(cfg).wall_clock)
        except EagleMissionError as exc:
            _print(err, f"invalid: {exc}")
            return run.EXIT_CONFIG
        try:
            recorder = RunRecorder(Path(args.record), when_full="wait" if virtual else "drop")
        except (FileExistsError, OSError) as exc:
            _print(err, f"error: --record {args.record}: {exc}")
            return run.EXIT_CONFIG
        hooks_kw.update(on_frame=recorder.write_frame, on_telemetry=recorder.write_state,
                        record_all=True)

    def prepare(asm: Any) -> None:
        if recorder is not None:
            recorder.set_models({c: cam.model for c, cam in asm.cameras.items()})

    options = run.FlightOptions(
        realtime=args.realtime, dry_run=args.dry_run,
        confirm=None if (args.yes or args.vehicle == "emulator") else _confirm,
        handle_signals=True, on_header=on_header, on_line=lambda s: _print(console, s),
        prepare=prepare, record=record_mcap, live=live_options,
        record_config=not (args.no_record or args.record),
        hooks=MissionHooks(log_path=Path(args.log) if args.log else None, on_state=on_state,
                           **hooks_kw))
    tmp = None
    try:
        with contextlib.ExitStack() as stack:
            if args.vehicle == "emulator":
                path, tmp = _mission_file_path(args.config)
                url = stack.enter_context(emulator_process(path))
                data["vehicle"] = {"type": "mavsdk",
                                   "params": {"url": url, "connect_timeout_s": 30}}
            try:
                cfg = MissionFile.model_validate(data)
            except ValueError as exc:
                _print(err, f"invalid: {exc}")
                return run.EXIT_CONFIG
            t0 = time.perf_counter()
            result = run.fly_sync(cfg, options)
    finally:
        if recorder is not None:
            recorder.close()
        if tmp is not None:
            os.unlink(tmp.name)
    if result.outcome is not None:
        for line in result.outcome.report_lines():
            _print(console, line)
        if args.plot and hasattr(result.outcome, "plot"):
            result.outcome.plot(Path(args.plot))
            _print(console, f"plot written to {args.plot}")
    if args.log and result.outcome is not None:
        _print(console, f"log written to {args.log}")
    if args.record and recorder is not None:
        _print(console, f"recording written to {args.record} ({recorder.stats})")
    if result.recording is not None:
        r = result.recording
        parts = f" in {r['parts']} parts" if r.get("parts", 1) > 1 else ""
        what = (f"recording written to {r.get('path', args.record)}{parts}: "
                f"{r['frames_written']} frames, "
                f"{r['records_written']} log records, {r['bytes'] / 1e6:.1f} MB, "
                f"{r['frames_dropped']} frames dropped, {r['write_errors']} write errors")
        _print(err if r["write_errors"] else console,
               what + (f" ({r['error']})" if r["error"] else ""))
    if result.live is not None:
        lv = result.live
        _print(err if lv["errors"] or lv["dropped"] else console,
               f"live view {lv['url']}: {lv['messages']} messages ({lv['images']} thumbnails, "
               f"{lv['bytes'] / 1e6:.2f} MB) published, {lv['throttled']} throttled, "
               f"{lv['dropped']} dropped, {lv['errors']} errors"
               + (f" ({lv['error']})" if lv["error"] else ""))
    if result.error and not result.dry_run:  # the dry run's checks said it, line by line
        _print(err, f"error: {result.error}")
    elif result.error and result.exit_code not in (run.EXIT_DONE, run.EXIT_PREFLIGHT):
        _print(err, f"error: {result.error}")
    _print(console, f"exit {result.exit_code} ({exit_name(result)}) after "
                    f"{time.perf_counter() - t0:.1f} s")
    return result.exit_code


def exit_name(result: Any) -> str:
    """What the exit code means for this run: a dry run never says DONE."""
    if result.dry_run and result.exit_code == 0:
        return "dry run passed: nothing armed"
    if result.dry_run and result.exit_code == 5:
        return "dry run failed: nothing armed"
    return EXIT_NAMES.get(result.exit_code, "?")


EXIT_NAMES = {0: "DONE", 1: "error", 2: "config refused", 3: "FAILSAFE",
              4: "connection failed", 5: "preflight refused", 6: "DONE, but off on ground truth",
              130: "interrupted"}

COMMAND = Command("fly a mission file (simulation, emulator, SITL, replay or field)", _add, _run)
